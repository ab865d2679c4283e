//! The displayable area (inside the mask, at the canvas aspect, near optimal and centred), the
//! placement of images into it, and the display range.

use super::*;
use compend::raster::ImageSize;

fn mask_of(w: usize, h: usize, f: impl Fn(f64, f64) -> bool) -> Mask<Unspecified> {
    // Pixel centres.
    Mask::from_fn(w, h, |x, y| f(x as f64 + 0.5, y as f64 + 0.5))
}

fn shapes(w: usize, h: usize) -> Vec<(&'static str, Mask<Unspecified>)> {
    let (fw, fh) = (w as f64, h as f64);
    vec![
        (
            "rectangle",
            mask_of(w, h, move |x, y| {
                x > 0.1 * fw && x < 0.85 * fw && y > 0.2 * fh && y < 0.9 * fh
            }),
        ),
        (
            "trapezoid",
            mask_of(w, h, move |x, y| {
                let t = y / fh;
                let half = fw * (0.2 + 0.25 * t);
                y > 0.05 * fh && y < 0.95 * fh && (x - 0.5 * fw).abs() < half
            }),
        ),
        (
            "disk",
            mask_of(w, h, move |x, y| {
                (x - 0.5 * fw).powi(2) + (y - 0.5 * fh).powi(2) < (0.45 * fh).powi(2)
            }),
        ),
        (
            "L",
            mask_of(w, h, move |x, y| {
                y < 0.95 * fh && (x < 0.4 * fw || y > 0.55 * fh)
            }),
        ),
        (
            "hole",
            mask_of(w, h, move |x, y| {
                let inside = x > 0.05 * fw && x < 0.95 * fw && y > 0.05 * fh && y < 0.95 * fh;
                let hole = (x - 0.45 * fw).abs() < 0.08 * fw && (y - 0.5 * fh).abs() < 0.1 * fh;
                inside && !hole
            }),
        ),
    ]
}

fn all_inside(mask: &Mask<Unspecified>, r: Rect) -> bool {
    (r.y..r.y + r.height).all(|y| (r.x..r.x + r.width).all(|x| mask.get(x, y)))
}

/// Largest area over every rectangle (every size and position, checked pixel by pixel) whose
/// sides satisfy `admissible(width, height)`.
fn brute_force(mask: &Mask<Unspecified>, admissible: impl Fn(usize, usize) -> bool) -> usize {
    let ImageSize {
        width: w,
        height: h,
    } = mask.size();
    let mut best = 0;
    for rh in 1..=h {
        for rw in 1..=w {
            if rw * rh <= best || !admissible(rw, rh) {
                continue;
            }
            'pos: for y in 0..=h - rh {
                for x in 0..=w - rw {
                    let r = Rect {
                        x,
                        y,
                        width: rw,
                        height: rh,
                    };
                    if all_inside(mask, r) {
                        best = rw * rh;
                        break 'pos;
                    }
                }
            }
        }
    }
    best
}

#[test]
fn displayable_area_is_inside_keeps_the_aspect_and_is_near_optimal() {
    for &(w, h) in &[(40usize, 30usize), (33, 41)] {
        for (name, mask) in shapes(w, h) {
            for aspect in [4.0 / 3.0, 16.0 / 9.0, 1.0, 0.75] {
                let r = displayable_area(&mask, aspect).unwrap();
                let what = format!("{name} {w}x{h} aspect {aspect:.3}: {r}");
                assert!(all_inside(&mask, r), "{what} leaves the mask");
                // Aspect within rounding of the shorter side.
                let err = if aspect >= 1.0 {
                    (r.height as f64 - r.width as f64 / aspect).abs()
                } else {
                    (r.width as f64 - r.height as f64 * aspect).abs()
                };
                assert!(err <= 0.5 + 1e-9, "{what}: aspect error {err}");
                // Against brute force: (a) the same rounding rule must give the same area;
                // (b) any rectangle within one pixel of the aspect is at most a few % larger.
                let same_rule = brute_force(&mask, |rw, rh| {
                    if aspect >= 1.0 {
                        rh == (rw as f64 / aspect).round() as usize
                    } else {
                        rw == (rh as f64 * aspect).round() as usize
                    }
                });
                assert_eq!(r.area(), same_rule, "{what}");
                let loose = brute_force(&mask, |rw, rh| {
                    (rw as f64 - aspect * rh as f64).abs() <= 1.0
                        || (rh as f64 - rw as f64 / aspect).abs() <= 1.0
                });
                assert!(
                    r.area() as f64 >= 0.9 * loose as f64,
                    "{what}: area {} vs {loose} within one pixel of the aspect",
                    r.area()
                );
            }
        }
    }
}

#[test]
fn displayable_area_prefers_the_centroid() {
    // A 40×20 lit block at columns 10..50, rows 12..32 of a 60×40 frame: the best square is
    // 20×20 and may slide horizontally; the mask's centroid (29.5, 21.5) picks columns 20..40.
    let mask = mask_of(60, 40, |x, y| x > 10.0 && x < 50.0 && y > 12.0 && y < 32.0);
    let r = displayable_area(&mask, 1.0).unwrap();
    assert_eq!(
        r,
        Rect {
            x: 20,
            y: 12,
            width: 20,
            height: 20
        }
    );
}

#[test]
fn displayable_area_of_a_detected_fov_is_truly_lit() {
    let r = render(&dark_scene(5));
    let fov = fov_mask(&r.black, &r.white, "dark").unwrap();
    let area = displayable_area(&fov.mask, 4.0 / 3.0).unwrap();
    let outside = (area.y..area.y + area.height)
        .flat_map(|y| (area.x..area.x + area.width).map(move |x| (x, y)))
        .filter(|&(x, y)| !r.truth.get(x, y))
        .count();
    eprintln!("dark FOV displayable area {area}, {outside} px not truly lit");
    assert!(
        outside as f64 <= 0.005 * area.area() as f64,
        "{area}: {outside} unlit pixels"
    );
    // It is large: the quadrilateral is about 140×100.
    assert!(area.width >= 110, "{area}");
}

#[test]
fn displayable_area_errors() {
    let empty = Mask::<Unspecified>::new(20, 10);
    let e = displayable_area(&empty, 4.0 / 3.0).unwrap_err();
    assert!(matches!(e, Error::Failed(_)), "{e:?}");
    assert!(e.to_string().contains("FOV mask"), "{e}");
    let full = Mask::<Unspecified>::full(20, 10);
    for bad in [0.0, -1.0, f64::NAN, f64::INFINITY] {
        let e = displayable_area(&full, bad).unwrap_err();
        assert!(matches!(e, Error::Input(_)), "{bad}: {e:?}");
    }
    // A full frame with its own aspect is the whole frame.
    assert_eq!(
        displayable_area(&full, 2.0).unwrap(),
        Rect {
            x: 0,
            y: 0,
            width: 20,
            height: 10
        }
    );
}

#[test]
fn resize_bilinear_uses_half_pixel_centres() {
    // Source row [0, 1] to 4 pixels: output x samples (x + 0.5)·2/4 − 0.5 =
    // −0.25, 0.25, 0.75, 1.25, clamped to [0, 1]: values 0, 0.25, 0.75, 1.
    let src = NetImage::from_fn(2, 1, |x, _| [x as f32, 0.5, 1.0 - x as f32]);
    let out = compend::resize::resize_bilinear(&src, 4, 1);
    let got: Vec<f32> = (0..4).map(|x| out.get(x, 0)[0]).collect();
    assert_eq!(got, vec![0.0, 0.25, 0.75, 1.0]);
    assert_eq!(out.get(1, 0)[1], 0.5);
    assert_eq!(out.get(1, 0)[2], 0.75);
    // Shrinking 4 → 2 averages the middle pairs: samples at 0.5 and 2.5.
    let src = NetImage::from_fn(4, 1, |x, _| [x as f32; 3]);
    let out = compend::resize::resize_bilinear(&src, 2, 1);
    assert_eq!((out.get(0, 0)[0], out.get(1, 0)[0]), (0.5, 2.5));
}

#[test]
fn place_in_area_fills_the_rectangle_carries_its_edge_a_margin_out_and_leaves_black_around() {
    let img = NetImage::from_fn(8, 8, |x, y| [x as f32 / 7.0, y as f32 / 7.0, 0.5]);
    let area = Rect {
        x: 5,
        y: 3,
        width: 12,
        height: 9,
    };
    let (cw, ch) = (26, 20);
    let out = place_in_area(&img, area, ImageSize::new(cw, ch)).unwrap();
    assert_eq!(out.size(), ImageSize::new(cw, ch));
    let m = compend::fov::EDGE_MARGIN_PX as i64;
    let (ax, ay) = (area.x as i64, area.y as i64);
    let (aw, ah) = (area.width as i64, area.height as i64);
    for y in 0..ch {
        for x in 0..cw {
            let p = out.get(x, y);
            let (xi, yi) = (x as i64, y as i64);
            let near = xi >= ax - m && yi >= ay - m && xi < ax + aw + m && yi < ay + ah + m;
            if area.contains(x, y) {
                assert_eq!(p[2], 0.5, "({x},{y})");
            } else if near {
                // The nearest pixel of the area, clamped into the canvas (the area starts 3 rows
                // from the top, less than the margin).
                let sx = xi.clamp(ax, ax + aw - 1) as usize;
                let sy = yi.clamp(ay, ay + ah - 1) as usize;
                assert_eq!(p, out.get(sx, sy), "({x},{y})");
            } else {
                assert_eq!(p, [0.0; 3], "({x},{y})");
            }
        }
    }
    // The margin is cut at the canvas: the top rows above the area carry its first row.
    assert_eq!(out.get(8, 0), out.get(8, 3));
    // Corners of the area carry the corners of the image (enlarging clamps to edge centres).
    assert_eq!(out.get(5, 3), [0.0, 0.0, 0.5]);
    assert_eq!(out.get(16, 11), [1.0, 1.0, 0.5]);
    // The ramp increases along the area.
    for x in 5..16 {
        assert!(out.get(x + 1, 6)[0] >= out.get(x, 6)[0]);
    }
    let outside = Rect {
        x: 10,
        y: 0,
        width: 12,
        height: 4,
    };
    assert!(matches!(
        place_in_area(&img, outside, ImageSize::new(cw, 2)),
        Err(Error::Shape(_))
    ));
}

#[test]
fn display_range_ignores_shadows_and_uses_quantiles() {
    use compend::fov::{DisplayRange, display_range};
    // 20x10 area: black level 0.1 + 0.001·x, white 0.8 − 0.002·x; the right 4 columns are shadow
    // (white = black), which must not pull the range down.
    let black = CamImage::from_fn(20, 10, |x, _| [0.1 + 0.001 * x as f32; 3]);
    let white = CamImage::from_fn(20, 10, |x, _| {
        if x >= 16 {
            [0.1 + 0.001 * x as f32; 3]
        } else {
            [0.8 - 0.002 * x as f32; 3]
        }
    });
    let area = Rect {
        x: 0,
        y: 0,
        width: 20,
        height: 10,
    };
    let r = display_range(&black, &white, area, 0.0).unwrap();
    // q = 0: the darkest white and brightest black among the 16 lit columns.
    assert!(
        (r.low - 0.115).abs() < 1e-6 && (r.high - 0.77).abs() < 1e-6,
        "{r:?}"
    );
    let img = CamImage::filled(2, 2, [0.0, 0.5, 1.0]);
    let mapped = r.apply(&img);
    assert!(
        (mapped.get(0, 0)[0] - r.low).abs() < 1e-6 && (mapped.get(0, 0)[2] - r.high).abs() < 1e-6
    );
    assert_eq!(DisplayRange::FULL.apply(&img), img);
    // Everything in shadow: a clear error.
    let err = display_range(&black, &black, area, 0.05).unwrap_err();
    assert!(
        err.to_string().contains("respond to the projector"),
        "{err}"
    );
}
