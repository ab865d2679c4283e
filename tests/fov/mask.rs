//! The FOV mask on rendered scenes: texture and specks, curved and dark regions, clipping,
//! notches, shadows, a frame lit everywhere, and the errors.

use super::*;

#[test]
fn fov_quadrilateral_with_colour_texture_and_specks() {
    let mut s = Scene::plain(quad(QUAD));
    s.albedo = Box::new(|x, y| {
        let v = cell_value(x, y, 9, 1);
        [
            0.2 + 0.7 * v,
            0.9 - 0.6 * v,
            0.3 + 0.5 * cell_value(x, y, 5, 2),
        ]
    });
    s.specks = 40;
    let r = render(&s);
    check("quad", &r, &FovOptions::default(), 0.97, 0.01);
}

#[test]
fn fov_curved_region_with_falloff() {
    let mut s = Scene::plain(curved);
    s.albedo = Box::new(|x, y| {
        let v = 0.5 + 0.4 * ((x as f32 * 0.21).sin() * (y as f32 * 0.17).cos());
        [v, v * 0.9, v * 0.8]
    });
    s.falloff = 0.6;
    s.specks = 20;
    let r = render(&s);
    let (cover, fp) = check("curved", &r, &FovOptions::default(), 0.97, 0.01);
    // The concave top edge: the hull option fills it with unlit pixels, the default does not.
    let hull = FovOptions {
        fill: FovFill::Hull,
        ..FovOptions::default()
    };
    let fov = fov_mask_with(&r.black, &r.white, "curved", &hull).unwrap();
    let (hcover, hfp) = score(&fov.mask, &r.truth);
    eprintln!("curved hull: cover {hcover:.4}, fp {hfp:.4} (default {cover:.4}, {fp:.4})");
    assert!(hfp > fp + 0.02, "hull should add the concave top bay");
}

#[test]
fn fov_dark_scene_keeps_the_dark_patches() {
    for seed in [3, 4, 5] {
        let r = render(&dark_scene(seed));
        // The scene is hard: the plain method loses a good part of the lit region.
        let (plain_cover, plain_fp) = score(&plain_otsu(&r), &r.truth);
        eprintln!("dark {seed}: plain Otsu covers {plain_cover:.4}, fp {plain_fp:.4}");
        assert!(plain_cover < 0.9, "plain Otsu covers {plain_cover:.4}");
        check(
            &format!("dark {seed}"),
            &r,
            &FovOptions::default(),
            0.97,
            0.01,
        );
    }
}

#[test]
fn fov_saturated_scene_fills_clipped_patches() {
    // Bright ambient light and high gain: bright patches clip in both captures, so
    // white − black is zero there; medium patches clip only in the white capture.
    let mut s = Scene::plain(quad(QUAD));
    s.albedo = Box::new(|x, y| {
        let v = cell_value(x, y, 10, 11);
        let a = if v < 0.25 { 0.95 } else { 0.15 + 0.4 * v };
        [a, a, a]
    });
    s.ambient = 0.5;
    s.projector = 0.9;
    s.gain = 2.2;
    s.specks = 10;
    let r = render(&s);
    let (plain_cover, _) = score(&plain_otsu(&r), &r.truth);
    eprintln!("saturated: plain Otsu covers {plain_cover:.4}");
    check("saturated", &r, &FovOptions::default(), 0.97, 0.01);
}

#[test]
fn fov_hull_recovers_a_black_notch_at_the_edge() {
    // A black band crosses the left edge of the lit region: no projector light comes back
    // from it at all. Closing cannot bridge 14 px; the convex hull does.
    let mut s = Scene::plain(quad(QUAD));
    s.albedo = Box::new(|x, y| {
        if (20..48).contains(&x) && (60..74).contains(&y) {
            [0.0; 3]
        } else {
            [0.5, 0.55, 0.6]
        }
    });
    let r = render(&s);
    let default = fov_mask(&r.black, &r.white, "notch").unwrap();
    let (dcover, _) = score(&default.mask, &r.truth);
    let hull = FovOptions {
        fill: FovFill::Hull,
        ..FovOptions::default()
    };
    let (hcover, hfp) = check("notch hull", &r, &hull, 0.99, 0.01);
    eprintln!("notch: default covers {dcover:.4}, hull {hcover:.4} (fp {hfp:.4})");
    assert!(dcover < hcover);
}

#[test]
fn fov_keeps_both_sides_of_a_shadow_and_drops_a_stray_reflection() {
    // The surface casts a 12 px shadow across the projection (a step), splitting the lit area
    // into two parts of about 60 % and 40 %; a small patch of reflected projector light lands on
    // another wall in the corner (about 2 % of the lit area). (A much thinner shadow is bridged:
    // with the low threshold at 3 % of the lit level, the blurred light of both sides meets
    // above it when it is narrower than about 4.3 σ of the total blur.)
    let inside = |x: f64, y: f64| {
        let main = quad(QUAD)(x, y) && !(85.0..97.0).contains(&(x + 0.1 * y));
        let stray = (5.0..20.0).contains(&x) && (132.0..146.0).contains(&y);
        main || stray
    };
    let mut s = Scene::plain(inside);
    s.albedo = Box::new(|x, y| [0.3 + 0.5 * cell_value(x, y, 7, 9); 3]);
    s.specks = 20;
    let r = render(&s);
    let stray = Mask::<Camera>::from_fn(W, H, |x, y| x < 24 && y > 128);
    let main_truth = Mask::from_fn(W, H, |x, y| r.truth.get(x, y) && !stray.get(x, y));
    let fov = fov_mask(&r.black, &r.white, "step").unwrap();
    let (cover, fp) = score(&fov.mask, &main_truth);
    eprintln!("step: cover {cover:.4}, fp {fp:.4} (stray counted as false)");
    assert!(cover >= 0.97 && fp <= 0.01, "cover {cover:.4}, fp {fp:.4}");
    assert_eq!(morph::connected_components(&fov.mask).count(), 2);
    // With `min_part` = 1 only the larger side is kept.
    let largest = FovOptions {
        min_part: 1.0,
        ..FovOptions::default()
    };
    let one = fov_mask_with(&r.black, &r.white, "step", &largest).unwrap();
    let (cover1, _) = score(&one.mask, &main_truth);
    assert!(
        cover1 > 0.5 && cover1 < 0.7,
        "largest side covers {cover1:.4}"
    );
}

#[test]
fn fov_lit_everywhere_is_the_whole_frame() {
    // The projection overfills the camera view: no background to measure the noise on, no edge.
    let mut s = Scene::plain(|_, _| true);
    s.albedo = Box::new(|x, y| [0.2 + 0.6 * cell_value(x, y, 9, 4); 3]);
    let r = render(&s);
    let fov = fov_mask(&r.black, &r.white, "overfilled").unwrap();
    assert_eq!(fov.mask.count(), W * H);
    assert_eq!(fov.diagnostics.noise_pixels, 0);
    assert_eq!(
        fov.bbox,
        Rect {
            x: 0,
            y: 0,
            width: W,
            height: H
        }
    );
}

#[test]
fn fov_errors_name_the_captures() {
    // Projector off: both captures show the same scene up to noise.
    let mut s = Scene::plain(|_, _| false);
    s.albedo = Box::new(|x, y| [cell_value(x, y, 8, 5); 3]);
    let r = render(&s);
    let e = fov_mask(
        &r.black,
        &r.white,
        "setup/cam/raw/ref/img_0001.png + img_0125.png",
    )
    .unwrap_err();
    let msg = e.to_string();
    assert!(matches!(e, Error::Failed(_)), "{e:?}");
    assert_eq!(e.exit_code(), 1);
    assert!(
        msg.contains("setup/cam/raw/ref/img_0001.png + img_0125.png"),
        "{msg}"
    );
    assert!(msg.contains("no projector light"), "{msg}");

    // A tiny lit spot (about 0.2 % of the frame).
    let r = render(&Scene::plain(|x, y| {
        (x - 100.0).abs() < 3.0 && (y - 70.0).abs() < 4.0
    }));
    let e = fov_mask(&r.black, &r.white, "ref pair").unwrap_err();
    let msg = e.to_string();
    assert!(matches!(e, Error::Failed(_)), "{e:?}");
    assert!(
        msg.contains("ref pair") && msg.contains("too small"),
        "{msg}"
    );

    // Captures of different sizes are an input error.
    let e = fov_mask(&CamImage::new(10, 8), &CamImage::new(8, 8), "pair").unwrap_err();
    assert!(matches!(e, Error::Input(_)), "{e:?}");
    assert_eq!(e.exit_code(), 2);
}
