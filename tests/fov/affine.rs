//! The affine initialisation from the FOV's bounding box (network to camera normalised
//! coordinates, align-corners).

use super::*;
use compend::raster::ImageSize;

/// Camera pixel coordinate of a normalised coordinate (align_corners = true), written out.
fn to_pixel(g: f32, n: usize) -> f32 {
    (g + 1.0) / 2.0 * (n - 1) as f32
}

#[test]
fn affine_maps_network_corners_to_box_corner_pixels() {
    let cam = ImageSize::new(640, 480);
    let bbox = Rect {
        x: 100,
        y: 50,
        width: 401,
        height: 301,
    };
    let theta = affine_from_box(bbox, cam).unwrap();
    // Network corners (−1,−1), (1,−1), (−1,1), (1,1) ↦ centres of the box's corner pixels.
    let corners = [
        ((-1.0, -1.0), (100.0, 50.0)),
        ((1.0, -1.0), (500.0, 50.0)),
        ((-1.0, 1.0), (100.0, 350.0)),
        ((1.0, 1.0), (500.0, 350.0)),
        ((0.0, 0.0), (300.0, 200.0)),
    ];
    for ((u, v), (px, py)) in corners {
        let (x, y) = apply_theta(&theta, u, v);
        let (cx, cy) = (to_pixel(x, cam.width), to_pixel(y, cam.height));
        assert!(
            (cx - px).abs() < 1e-3 && (cy - py).abs() < 1e-3,
            "({u},{v}) -> ({cx},{cy})"
        );
    }
    // No rotation or shear.
    assert_eq!(theta[0][1], 0.0);
    assert_eq!(theta[1][0], 0.0);

    // The whole frame is the identity.
    let id = affine_from_box(
        Rect {
            x: 0,
            y: 0,
            width: 640,
            height: 480,
        },
        cam,
    )
    .unwrap();
    assert_eq!(id, [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]);

    // A box that leaves the frame is refused.
    let bad = Rect {
        x: 600,
        y: 0,
        width: 41,
        height: 10,
    };
    assert!(matches!(affine_from_box(bad, cam), Err(Error::Shape(_))));
}

#[test]
fn affine_from_a_detected_fov_covers_its_box() {
    let r = render(&Scene::plain(quad(QUAD)));
    let fov = fov_mask(&r.black, &r.white, "quad").unwrap();
    let theta = affine_from_box(fov.bbox, ImageSize::new(W, H)).unwrap();
    let b = fov.bbox;
    let (x0, y0) = apply_theta(&theta, -1.0, -1.0);
    let (x1, y1) = apply_theta(&theta, 1.0, 1.0);
    assert!((to_pixel(x0, W) - b.x as f32).abs() < 1e-3);
    assert!((to_pixel(y0, H) - b.y as f32).abs() < 1e-3);
    assert!((to_pixel(x1, W) - (b.x + b.width - 1) as f32).abs() < 1e-3);
    assert!((to_pixel(y1, H) - (b.y + b.height - 1) as f32).abs() < 1e-3);
    // The box is the quadrilateral's extent (corners at x 28.3..176.2, y 20.6..131.4), to a
    // pixel.
    assert!(
        (b.x as i64 - 28).abs() <= 1 && (b.y as i64 - 20).abs() <= 1,
        "{b}"
    );
    assert!(((b.x + b.width) as i64 - 176).abs() <= 1, "{b}");
    assert!(((b.y + b.height) as i64 - 131).abs() <= 1, "{b}");
}
