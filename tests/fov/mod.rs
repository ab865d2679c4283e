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
//!
//! Submodules: `mask` (the FOV mask on rendered scenes), `affine` (the affine initialisation),
//! `area` (the displayable area, placement and display range). The scene renderer and the checks
//! shared by them are here. All masks and images are in camera pixels.

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

mod affine;
mod area;
mod mask;

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
