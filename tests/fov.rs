//! Projector FOV mask, affine initialisation and displayable area on synthetic captures.
//!
//! The scenes are rendered here: a lit region (the projector's image on the surface, in camera
//! pixels) given as a point-in-region test on continuous coordinates (pixel (x, y) covers
//! [x, x+1) × [y, y+1)), a textured albedo, ambient light, projector light with fall-off and
//! defocus, camera gain with clipping at 1, Gaussian noise, 8-bit quantisation, and bright
//! specks outside the lit region in the white capture. The true lit region is the set of pixels
//! at least half covered by the region (4×4 supersampling).
//!
//! Set `FOV_DUMP=DIR` to write, per checked scene, the white capture and a picture of the mask
//! against the truth (red: missed, green: false positive).

use compend::Error;
use compend::filter::gaussian_blur;
use compend::fov::{
    FovFill, FovOptions, affine_from_box, apply_theta, displayable_area, fov_mask, fov_mask_with,
    place_in_area,
};
use compend::morph;
use compend::raster::{CamImage, Camera, Mask, NetImage, Plane, Rect, Unspecified};
use rand::rngs::ChaCha8Rng;
use rand::{RngExt, SeedableRng};

const W: usize = 200;
const H: usize = 150;

struct Scene {
    /// Is continuous camera position (x, y) inside the lit region?
    inside: Box<dyn Fn(f64, f64) -> bool>,
    /// Albedo per camera pixel and channel, in [0, 1].
    albedo: Box<dyn Fn(usize, usize) -> [f32; 3]>,
    ambient: f32,
    /// Projector white level at the region's centre.
    projector: f32,
    /// Fraction of projector light lost at distance 100 px from the frame centre (quadratic).
    falloff: f32,
    /// Camera gain (values above 1 clip).
    gain: f32,
    /// Noise σ per channel, per capture.
    noise: f32,
    /// Blur σ (pixels) of the projector light at the surface (defocus).
    defocus: f64,
    /// Single-pixel bright specks added to the white capture outside the lit region.
    specks: usize,
    seed: u64,
}

impl Scene {
    fn plain(inside: impl Fn(f64, f64) -> bool + 'static) -> Self {
        Scene {
            inside: Box::new(inside),
            albedo: Box::new(|_, _| [0.6, 0.6, 0.6]),
            ambient: 0.1,
            projector: 0.8,
            falloff: 0.0,
            gain: 1.0,
            noise: 0.01,
            defocus: 0.7,
            specks: 0,
            seed: 1,
        }
    }
}

struct Rendered {
    black: CamImage,
    white: CamImage,
    truth: Mask<Camera>,
}

fn quantize(v: f32) -> f32 {
    (v.clamp(0.0, 1.0) * 255.0).round() / 255.0
}

fn render(s: &Scene) -> Rendered {
    let mut rng = ChaCha8Rng::seed_from_u64(s.seed);
    let coverage = Plane::<Camera>::from_fn(W, H, |x, y| {
        let mut c = 0;
        for j in 0..4 {
            for i in 0..4 {
                let (px, py) = (
                    x as f64 + (i as f64 + 0.5) / 4.0,
                    y as f64 + (j as f64 + 0.5) / 4.0,
                );
                c += (s.inside)(px, py) as u32;
            }
        }
        c as f32 / 16.0
    });
    let truth = Mask::from_fn(W, H, |x, y| coverage.get(x, y) >= 0.5);
    let light = gaussian_blur(&coverage, s.defocus);
    let mut black = CamImage::new(W, H);
    let mut white = CamImage::new(W, H);
    let gauss = |rng: &mut ChaCha8Rng| {
        // Box–Muller.
        let (u1, u2) = (rng.random::<f32>().max(1e-7), rng.random::<f32>());
        (-2.0 * u1.ln()).sqrt() * (std::f32::consts::TAU * u2).cos()
    };
    for y in 0..H {
        for x in 0..W {
            let a = (s.albedo)(x, y);
            let r2 = ((x as f32 - W as f32 / 2.0).powi(2) + (y as f32 - H as f32 / 2.0).powi(2))
                / 100.0f32.powi(2);
            let p = s.projector * (1.0 - s.falloff * r2).max(0.0) * light.get(x, y);
            let mut b = [0.0; 3];
            let mut wv = [0.0; 3];
            for c in 0..3 {
                b[c] = quantize(s.gain * a[c] * s.ambient + s.noise * gauss(&mut rng));
                wv[c] = quantize(s.gain * a[c] * (s.ambient + p) + s.noise * gauss(&mut rng));
            }
            black.set(x, y, b);
            white.set(x, y, wv);
        }
    }
    // Specks: bright pixels in the white capture only, at least 4 px from the lit region.
    let far = morph::dilate(&truth, morph::Element::Square(4));
    let mut placed = 0;
    while placed < s.specks {
        let (x, y) = (rng.random_range(0..W), rng.random_range(0..H));
        if !far.get(x, y) {
            white.set(x, y, [0.9, 0.8, 0.9]);
            placed += 1;
        }
    }
    Rendered {
        black,
        white,
        truth,
    }
}

/// (fraction of the true region covered, false positives as a fraction of the true region).
fn score(mask: &Mask<Camera>, truth: &Mask<Camera>) -> (f64, f64) {
    let (mut tp, mut fp) = (0usize, 0usize);
    for (&m, &t) in mask.data().iter().zip(truth.data()) {
        tp += (m && t) as usize;
        fp += (m && !t) as usize;
    }
    let n = truth.count() as f64;
    (tp as f64 / n, fp as f64 / n)
}

/// Pseudo-random cell texture: each `cell`-pixel square gets a value from a hash of its index.
fn cell_value(x: usize, y: usize, cell: usize, salt: u64) -> f32 {
    let (cx, cy) = ((x / cell) as u64, (y / cell) as u64);
    let mut h = cx
        .wrapping_mul(0x9E37_79B9_7F4A_7C15)
        .wrapping_add(cy.wrapping_mul(0xC2B2_AE3D_27D4_EB4F))
        .wrapping_add(salt.wrapping_mul(0x1656_67B1_9E37_79F9));
    h ^= h >> 29;
    h = h.wrapping_mul(0xBF58_476D_1CE4_E5B9);
    h ^= h >> 32;
    (h % 10_000) as f32 / 10_000.0
}

/// A quadrilateral through four corners (any orientation), as a point-in-convex-polygon test.
fn quad(pts: [(f64, f64); 4]) -> impl Fn(f64, f64) -> bool {
    move |x, y| {
        let mut sign = 0.0f64;
        for i in 0..4 {
            let (a, b) = (pts[i], pts[(i + 1) % 4]);
            let c = (b.0 - a.0) * (y - a.1) - (b.1 - a.1) * (x - a.0);
            if c != 0.0 {
                if sign == 0.0 {
                    sign = c.signum();
                } else if c.signum() != sign {
                    return false;
                }
            }
        }
        true
    }
}

const QUAD: [(f64, f64); 4] = [(28.3, 20.6), (176.2, 30.1), (166.8, 131.4), (36.5, 121.7)];

/// A region with curved sides: left/right edges bow outwards, the top edge bows inwards
/// (a concave side, as on a curved surface), the bottom edge is a sine wave.
fn curved(x: f64, y: f64) -> bool {
    let top = 24.0 + 10.0 * ((x - 30.0) / 140.0 * std::f64::consts::PI).sin();
    let bottom = 125.0 + 3.0 * (x / 15.0).sin();
    let half = 70.0 + 8.0 * ((y - 24.0) / 101.0 * std::f64::consts::PI).sin();
    y >= top && y <= bottom && (x - 100.0).abs() <= half
}

fn check(name: &str, r: &Rendered, opt: &FovOptions, min_cover: f64, max_fp: f64) -> (f64, f64) {
    let fov = fov_mask_with(&r.black, &r.white, name, opt).expect("FOV found");
    let (cover, fp) = score(&fov.mask, &r.truth);
    eprintln!(
        "{name}: cover {:.4}, fp {:.4}, diagnostics {:?}",
        cover, fp, fov.diagnostics
    );
    if let Ok(dir) = std::env::var("FOV_DUMP") {
        let vis = CamImage::from_fn(W, H, |x, y| {
            let (m, t) = (fov.mask.get(x, y), r.truth.get(x, y));
            let g = r.white.get(x, y)[1] * 0.5;
            match (m, t) {
                (true, true) => [0.5 + g, 0.5 + g, 0.5 + g],
                (false, true) => [1.0, 0.0, 0.0],
                (true, false) => [0.0, 1.0, 0.0],
                _ => [g, g, g],
            }
        });
        let p = std::path::Path::new(&dir).join(format!("{}.png", name.replace(' ', "_")));
        compend::pngio::write_rgb(&p, &vis).unwrap();
        let p = std::path::Path::new(&dir).join(format!("{}_white.png", name.replace(' ', "_")));
        compend::pngio::write_rgb(&p, &r.white).unwrap();
    }
    assert!(
        cover >= min_cover,
        "{name}: covers {cover:.4} of the lit region"
    );
    assert!(
        fp <= max_fp,
        "{name}: false positives {fp:.4} of the lit region"
    );
    assert_eq!(Some(fov.bbox), fov.mask.bounding_box());
    let d = &fov.diagnostics;
    assert!((d.coverage - fov.mask.count() as f64 / (W * H) as f64).abs() < 1e-12);
    assert!(d.threshold <= d.otsu_threshold && d.threshold > 0.0);
    (cover, fp)
}

/// The plain method: Otsu on the blurred difference, largest region, holes filled.
fn plain_otsu(r: &Rendered) -> Mask<Camera> {
    let diff = CamImage::from_vec(
        W,
        H,
        r.white
            .data()
            .iter()
            .zip(r.black.data())
            .map(|(a, b)| (a - b).max(0.0))
            .collect(),
    )
    .unwrap();
    let d = gaussian_blur(&diff.to_gray(), 1.0);
    let t = morph::otsu_threshold(&d);
    morph::fill_holes(&morph::largest_component(&d.threshold(t)))
}

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

/// A dark scene: low ambient light and a dark surface whose texture has near-black patches,
/// where white − black is a few 8-bit levels (about the camera noise), plus brightness
/// fall-off towards the corners.
fn dark_scene(seed: u64) -> Scene {
    let mut s = Scene::plain(quad(QUAD));
    s.albedo = Box::new(|x, y| {
        let v = cell_value(x, y, 11, 7);
        let a = if v < 0.35 {
            0.025 // dark patches: white − black ≈ 0.025 · projector ≈ 4 levels
        } else if v < 0.42 {
            0.004 // near-black patches: below the noise
        } else {
            0.08 + 0.25 * (v - 0.42)
        };
        let tint = cell_value(x, y, 4, 8);
        [a * (0.8 + 0.4 * tint), a, a * (1.2 - 0.4 * tint)]
    });
    s.ambient = 0.03;
    s.projector = 0.7;
    s.falloff = 0.5;
    s.noise = 0.006;
    s.specks = 30;
    s.seed = seed;
    s
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

// ---------------------------------------------------------------------------------------------
// Affine initialisation
// ---------------------------------------------------------------------------------------------

/// Camera pixel coordinate of a normalised coordinate (align_corners = true), written out.
fn to_pixel(g: f32, n: usize) -> f32 {
    (g + 1.0) / 2.0 * (n - 1) as f32
}

#[test]
fn affine_maps_network_corners_to_box_corner_pixels() {
    let cam = (640, 480);
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
        let (cx, cy) = (to_pixel(x, cam.0), to_pixel(y, cam.1));
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
    let theta = affine_from_box(fov.bbox, (W, H)).unwrap();
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

// ---------------------------------------------------------------------------------------------
// Displayable area
// ---------------------------------------------------------------------------------------------

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
    let (w, h) = mask.size();
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
fn place_in_area_fills_the_rectangle_and_leaves_black_around() {
    let img = NetImage::from_fn(8, 8, |x, y| [x as f32 / 7.0, y as f32 / 7.0, 0.5]);
    let area = Rect {
        x: 5,
        y: 3,
        width: 12,
        height: 9,
    };
    let out = place_in_area(&img, area, (20, 15)).unwrap();
    assert_eq!(out.size(), (20, 15));
    for y in 0..15 {
        for x in 0..20 {
            let p = out.get(x, y);
            if area.contains(x, y) {
                assert_eq!(p[2], 0.5, "({x},{y})");
            } else {
                assert_eq!(p, [0.0; 3], "({x},{y})");
            }
        }
    }
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
        place_in_area(&img, outside, (20, 15)),
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
