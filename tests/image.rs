//! The image core: PNG round trips, resizing and grid sampling conventions.

use compend::pngio;
use compend::raster::{Camera, ImageSize, Mask, Network, Rgb};
use compend::resize::{resize_area, resize_bilinear, unstretch};
use compend::sample::{Grid, grid_sample, norm_to_pixel, pixel_to_norm};

fn ramp(w: usize, h: usize) -> Rgb<Camera> {
    Rgb::from_fn(w, h, |x, y| {
        [x as f32 / (w - 1) as f32, y as f32 / (h - 1) as f32, 0.25]
    })
}

#[test]
fn png_round_trip_rounds_to_nearest() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("sub/img.png");
    // 0.5/255 above a level rounds up, just below rounds down; out of range clamps.
    let img = Rgb::<Camera>::from_vec(
        2,
        2,
        vec![
            10.51 / 255.0,
            10.49 / 255.0,
            0.0, //
            1.2,
            -0.3,
            1.0, //
            128.0 / 255.0,
            0.999_999,
            254.6 / 255.0, //
            f32::NAN,
            0.5,
            0.25,
        ],
    )
    .unwrap();
    pngio::write_rgb(&path, &img).unwrap();
    let back = pngio::read_rgb::<Camera>(&path).unwrap();
    let bytes: Vec<u8> = back
        .data()
        .iter()
        .map(|&v| (v * 255.0).round() as u8)
        .collect();
    assert_eq!(
        bytes,
        vec![11, 10, 0, 255, 0, 255, 128, 255, 255, 0, 128, 64]
    );
    assert_eq!(pngio::png_size(&path).unwrap(), ImageSize::new(2, 2));
    // No temporary file is left behind.
    let names: Vec<_> = std::fs::read_dir(path.parent().unwrap()).unwrap().collect();
    assert_eq!(names.len(), 1);
}

#[test]
fn png_sized_read_names_the_file_and_sizes() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("cap.png");
    pngio::write_rgb(&path, &Rgb::<Camera>::new(5, 4)).unwrap();
    let err =
        pngio::read_rgb_sized::<Camera>(&path, ImageSize::new(6, 4), "camera size").unwrap_err();
    let msg = err.to_string();
    assert!(
        msg.contains("cap.png") && msg.contains("5x4") && msg.contains("6x4"),
        "{msg}"
    );
    assert_eq!(err.exit_code(), 2);
}

#[test]
fn mask_png_round_trip() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("mask.png");
    let m = Mask::<Camera>::from_fn(7, 5, |x, y| (x + y) % 3 == 0);
    pngio::write_mask(&path, &m).unwrap();
    assert_eq!(pngio::read_mask::<Camera>(&path).unwrap(), m);
}

#[test]
fn area_resize_averages_blocks() {
    let img = Rgb::<Camera>::from_fn(4, 2, |x, y| [(x + 4 * y) as f32, 0.0, 1.0]);
    let half = resize_area(&img, 2, 1);
    // Block (0..2, 0..2) holds 0,1,4,5 → 2.5; block (2..4) holds 2,3,6,7 → 4.5.
    assert_eq!(half.get(0, 0), [2.5, 0.0, 1.0]);
    assert_eq!(half.get(1, 0), [4.5, 0.0, 1.0]);
    // Non-integer ratio: 3 → 2 weights pixel 1 half to each output.
    let row = Rgb::<Camera>::from_fn(3, 1, |x, _| [x as f32 * 3.0, 0.0, 0.0]);
    let two = resize_area(&row, 2, 1);
    // out0 = (0·1 + 3·0.5) / 1.5 = 1, out1 = (3·0.5 + 6·1) / 1.5 = 5
    assert!((two.get(0, 0)[0] - 1.0).abs() < 1e-6 && (two.get(1, 0)[0] - 5.0).abs() < 1e-6);
}

#[test]
fn bilinear_resize_half_pixel_centres() {
    // Upscaling 2 → 4 samples source positions -0.25 (clamped to 0), 0.25, 0.75, 1.25 (clamped).
    let row = Rgb::<Camera>::from_fn(2, 1, |x, _| [x as f32, 0.0, 0.0]);
    let up = resize_bilinear(&row, 4, 1);
    let got: Vec<f32> = (0..4).map(|x| up.get(x, 0)[0]).collect();
    assert_eq!(got, vec![0.0, 0.25, 0.75, 1.0]);
    // A constant stays constant at any size.
    let c = Rgb::<Camera>::filled(7, 5, [0.3, 0.6, 0.9]);
    for px in resize_bilinear(&c, 13, 3).data().chunks(3) {
        assert!((px[0] - 0.3).abs() < 1e-6 && (px[2] - 0.9).abs() < 1e-6);
    }
}

#[test]
fn unstretch_inverts_the_canvas_stretch() {
    // A small image stretched bilinearly to a finer size comes back exactly (least squares of a
    // full-rank enlargement), where a bilinear or area shrink blurs it.
    let img = Rgb::<Camera>::from_fn(9, 7, |x, y| {
        let v = ((x * 7 + y * 13) % 11) as f32 / 10.0;
        [v, 1.0 - v, (x as f32 / 8.0) * v]
    });
    let big = resize_bilinear(&img, 14, 11);
    let back = unstretch(&big, 9, 7);
    let worst = |a: &Rgb<Camera>| {
        a.data()
            .iter()
            .zip(img.data())
            .map(|(p, q)| (p - q).abs())
            .fold(0f32, f32::max)
    };
    assert!(worst(&back) < 1e-4, "unstretch error {}", worst(&back));
    assert!(worst(&resize_bilinear(&big, 9, 7)) > 0.05);
    assert!(worst(&resize_area(&big, 9, 7)) > 0.05);
    // Same size: unchanged; not smaller: a bilinear resize.
    assert_eq!(unstretch(&img, 9, 7).data(), img.data());
    assert_eq!(
        unstretch(&img, 12, 9).data(),
        resize_bilinear(&img, 12, 9).data()
    );
}

#[test]
fn normalised_coordinates_align_corners() {
    assert_eq!(pixel_to_norm(0.0, 5), -1.0);
    assert_eq!(pixel_to_norm(4.0, 5), 1.0);
    assert_eq!(pixel_to_norm(2.0, 5), 0.0);
    assert_eq!(norm_to_pixel(1.0, 9), 8.0);
    assert_eq!(norm_to_pixel(-1.0, 9), 0.0);
}

#[test]
fn identity_grid_reproduces_the_image() {
    let img = ramp(9, 7);
    let out = grid_sample(&img, &Grid::<Camera, Camera>::identity(9, 7));
    for (a, b) in out.data().iter().zip(img.data()) {
        assert!((a - b).abs() < 1e-6);
    }
}

#[test]
fn grid_sample_matches_hand_computed_bilinear_and_zero_padding() {
    // 2×2 source: values 0, 1 / 2, 3 in channel 0.
    let src = Rgb::<Camera>::from_fn(2, 2, |x, y| [(x + 2 * y) as f32, 0.0, 0.0]);
    let grid = Grid::<Network, Camera>::from_vec(
        4,
        1,
        vec![
            [0.0, 0.0],   // centre: mean of all four = 1.5
            [-1.0, -1.0], // first pixel centre exactly = 0
            [2.0, -1.0],  // pixel coordinate (1.5, 0): half of pixel 1, half outside → 0.5
            [-3.0, 0.0],  // fully outside → 0
        ],
    )
    .unwrap();
    let out = grid_sample(&src, &grid);
    let got: Vec<f32> = (0..4).map(|x| out.get(x, 0)[0]).collect();
    assert_eq!(got, vec![1.5, 0.0, 0.5, 0.0]);
}

#[test]
fn affine_grid_and_composition() {
    let img = ramp(11, 11);
    // θ = half scale about the centre: the output shows the middle half of the source.
    let theta = [[0.5, 0.0, 0.0], [0.0, 0.5, 0.0]];
    let grid = Grid::<Network, Camera>::affine(&theta, 11, 11);
    let out = grid_sample(&img, &grid);
    // Output pixel 0 maps to normalised -0.5 → source pixel 2.5 → value 0.25.
    assert!((out.get(0, 0)[0] - 0.25).abs() < 1e-6);
    assert!((out.get(10, 10)[1] - 0.75).abs() < 1e-6);
    // Composing two half-scale grids equals one quarter-scale grid (inner grid is affine, so
    // bilinear interpolation of coordinates is exact).
    let inner = Grid::<Camera, Camera>::affine(&theta, 11, 11);
    let outer = Grid::<Network, Camera>::affine(&theta, 11, 11);
    let composed = outer.compose(&inner);
    let quarter = Grid::<Network, Camera>::affine(&[[0.25, 0.0, 0.0], [0.0, 0.25, 0.0]], 11, 11);
    for (a, b) in composed.data().iter().zip(quarter.data()) {
        assert!((a[0] - b[0]).abs() < 1e-6 && (a[1] - b[1]).abs() < 1e-6);
    }
}
