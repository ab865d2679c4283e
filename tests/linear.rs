//! The `linear` model on a synthetic projector-camera system with a known answer.

use compend::linear::{ColourSolve, ColourSums, FitSettings, GeometryMemo, fit, fit_with_memo};
use compend::metrics;
use compend::raster::{CamImage, Camera, ImageSize, NetImage, Network, Rgb};
use compend::sample::{Grid, grid_sample, pixel_to_norm};
use compend::warp::Warp;

use crate::common::max_abs;
use rand::rngs::ChaCha8Rng;
use rand::{RngExt, SeedableRng};

pub const NET: usize = 32;
const CAM: ImageSize = ImageSize::new(48, 40);

/// A smooth random colour image (sum of a few sinusoids per channel).
pub fn texture(rng: &mut ChaCha8Rng) -> NetImage {
    let params: Vec<[f32; 5]> = (0..9)
        .map(|_| {
            [
                rng.random_range(0.5..4.0),
                rng.random_range(0.5..4.0),
                rng.random_range(0.0..6.3),
                rng.random_range(0.1..0.3),
                rng.random_range(0.0..1.0),
            ]
        })
        .collect();
    Rgb::from_fn(NET, NET, |x, y| {
        let (u, v) = (x as f32 / NET as f32, y as f32 / NET as f32);
        let mut px = [0.5f32; 3];
        for (i, p) in params.iter().enumerate() {
            px[i % 3] += p[3] * (p[0] * u * 6.0 + p[1] * v * 6.0 + p[2]).sin();
        }
        px.map(|c| c.clamp(0.0, 1.0))
    })
}

/// The simulated system: camera pixel q sees projector (network) position P(q) (a gentle
/// perspective-like bend), reflectance ρ(q) per channel, ambient a(q); gammas 2.0 / 2.2.
pub struct System {
    to_prj: Grid<Camera, Network>,
    albedo: CamImage,
    ambient: CamImage,
    /// When set, the projector has this many pixels per side and shows a network image
    /// stretched over them (bilinear, half-pixel centres: what the canvas does); when not, its
    /// pixels are the network image's.
    projector: Option<usize>,
}

impl System {
    pub fn new() -> Self {
        Self::with(CAM, None)
    }

    /// The system seen by a `cam`-sized camera; with `Some(side)`, a `side`² projector that
    /// stretches network images over its frame.
    pub fn with(cam: ImageSize, projector: Option<usize>) -> Self {
        let ImageSize {
            width: cw,
            height: ch,
        } = cam;
        let to_prj = Grid::from_fn(cw, ch, |x, y| {
            let (u, v) = (pixel_to_norm(x as f32, cw), pixel_to_norm(y as f32, ch));
            // The projector covers a central region of the camera view, slightly bent.
            let px = 1.25 * u + 0.08 * v * v - 0.03;
            let py = 1.2 * v + 0.06 * u * u + 0.04 * u;
            [px, py]
        });
        let albedo = Rgb::from_fn(cw, ch, |x, y| {
            let s = ((x / 6 + y / 5) % 2) as f32;
            [0.55 + 0.3 * s, 0.7 - 0.2 * s, 0.5 + 0.1 * s]
        });
        let ambient = Rgb::from_fn(cw, ch, |x, _| {
            [0.02 + 0.02 * x as f32 / cw as f32, 0.02, 0.03]
        });
        Self {
            to_prj,
            albedo,
            ambient,
            projector,
        }
    }

    /// Captures a projector image shown on the system.
    pub fn capture(&self, prj: &NetImage) -> CamImage {
        let shown = match self.projector {
            Some(side) => compend::resize::resize_bilinear(prj, side, side),
            None => prj.clone(),
        };
        let lin = shown.map(|v| v.max(0.0).powf(2.2));
        let seen = grid_sample(&lin, &self.to_prj);
        let mut out = seen.clone();
        for (i, v) in out.data_mut().iter_mut().enumerate() {
            let l = self.albedo.data()[i] * *v + self.ambient.data()[i];
            *v = (l.clamp(0.0, 1.0)).powf(1.0 / 2.0);
        }
        compend::pngio::quantize(&out)
    }
}

/// Seeded training (24) and test (6) textures and their captures on `sys`.
fn pairs(sys: &System, seed: u64) -> [Vec<(NetImage, CamImage)>; 2] {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    [24, 6].map(|n| {
        (0..n)
            .map(|_| {
                let t = texture(&mut rng);
                let c = sys.capture(&t);
                (t, c)
            })
            .collect()
    })
}

/// The fit's settings at the tests' network size: two geometry levels at full resolution.
fn settings() -> FitSettings {
    FitSettings {
        network_size: ImageSize::new(NET, NET),
        levels: vec![(NET, 150, 1.0), (NET, 100, 0.0)],
        ..FitSettings::default()
    }
}

#[test]
fn linear_fit_generalises_and_compensates() {
    let [tr, te] = pairs(&System::new(), 7);
    let (train, caps): (Vec<NetImage>, Vec<CamImage>) = tr.into_iter().unzip();
    let (test, test_caps): (Vec<NetImage>, Vec<CamImage>) = te.into_iter().unzip();

    // Initial affine: the inverse of the linear part of P, roughly (what a bounding box gives).
    let init = Warp::from_affine([[0.8, 0.0, 0.02], [0.0, 0.83, 0.0]]);
    let settings = settings();
    let (affine_only, _) = fit(
        &caps,
        &train,
        init.clone(),
        &FitSettings {
            learn_geometry: false,
            ..settings.clone()
        },
        |_, _, _| {},
    )
    .unwrap();
    let (model, report) = fit(&caps, &train, init, &settings, |_, _, _| {}).unwrap();
    let first = report.loss_history[0];
    let last = *report.loss_history.last().unwrap();
    assert!(
        last < 0.5 * first,
        "geometry optimisation lowers the loss: {first} → {last}"
    );

    // Paper protocol on held-out pairs: the model maps test captures back to the projector inputs.
    let score = |m: &compend::linear::LinearModel| {
        let s = m.simplify();
        let preds: Vec<NetImage> = test_caps.iter().map(|c| s.apply(c)).collect();
        metrics::score_pairs(preds.iter().zip(&test)).unwrap()
    };
    let learned = score(&model);
    eprintln!(
        "loss {first:.3e} -> {last:.3e}; learned {learned:?}; curves {:?}; warp theta {:?}",
        model.curves, model.geometry
    );
    let fixed = score(&affine_only);
    eprintln!("affine only {fixed:?}");
    assert!(learned.psnr > 28.0, "held-out PSNR {:.2} dB", learned.psnr);
    assert!(
        learned.psnr > fixed.psnr + 3.0,
        "learned geometry {:.2} dB should beat the initial affine {:.2} dB",
        learned.psnr,
        fixed.psnr
    );
}

/// A finer output lattice (docs/architecture.md, "Spaces and conventions": network space is what
/// the models see; the `linear` rungs may write a finer image, which the canvas stretches like
/// any other). On a system whose projector
/// stretches images as the canvas does, the lattice fit scored at the network size must beat
/// the network-size fit.
#[test]
fn linear_fit_on_a_finer_lattice_matches_the_canvas_stretch() {
    // A camera finer than the lattice (as on the rig: 640×480 against a 384² lattice); a
    // lattice finer than the camera only interpolates between camera pixels.
    let [tr, te] = pairs(&System::with(ImageSize::new(96, 80), Some(96)), 11);
    let (train, caps): (Vec<NetImage>, Vec<CamImage>) = tr.into_iter().unzip();
    let (test, test_caps): (Vec<NetImage>, Vec<CamImage>) = te.into_iter().unzip();
    let init = Warp::from_affine([[0.8, 0.0, 0.02], [0.0, 0.83, 0.0]]);
    let settings = settings();
    // Scored at the network size: the lattice output is brought back by `unstretch`.
    let score = |lattice: Option<ImageSize>| {
        let s = FitSettings {
            lattice,
            ..settings.clone()
        };
        let (m, _) = fit(&caps, &train, init.clone(), &s, |_, _, _| {}).unwrap();
        assert_eq!(
            m.network_size(),
            lattice.unwrap_or(ImageSize::new(NET, NET))
        );
        let simplified = m.simplify();
        let preds: Vec<NetImage> = test_caps
            .iter()
            .map(|c| compend::model::at_size(simplified.apply(c), ImageSize::new(NET, NET)))
            .collect();
        metrics::score_pairs(preds.iter().zip(&test)).unwrap()
    };
    let (net, fine) = (score(None), score(Some(ImageSize::new(48, 48))));
    eprintln!("network {net:?}; lattice 48² {fine:?}");
    assert!(net.psnr > 28.0, "network-size fit {:.2} dB", net.psnr);
    // Measured: 38.77 dB at the network size, 39.83 dB on the lattice (evaluating the warp at
    // align-corners lattice coordinates instead of the stretched pixel centres gave 31.9 dB).
    assert!(
        fine.psnr > net.psnr,
        "lattice 48²: {:.2} dB against {:.2} dB at the network size",
        fine.psnr,
        net.psnr
    );
}

/// The `linear` fits of one training share their geometry ([`GeometryMemo`]): a fit on more
/// pairs after the same first `geometry_images` takes the memo's geometry, and gives what a fit
/// of its own gives; a fit whose first pairs or geometry settings differ fits its own, while
/// another lattice (the colour solve's alone) still shares it.
#[test]
fn fits_on_the_same_first_pairs_share_their_geometry() {
    let [tr, _] = pairs(&System::new(), 5);
    let (train, caps): (Vec<NetImage>, Vec<CamImage>) = tr.into_iter().unzip();
    let init = Warp::from_affine([[0.8, 0.0, 0.02], [0.0, 0.83, 0.0]]);
    let settings = FitSettings {
        geometry_images: 12,
        ..settings()
    };
    let memo = GeometryMemo::default();
    let fit_on = |caps: &[CamImage], train: &[NetImage], s: &FitSettings| {
        fit_with_memo(caps, train, init.clone(), s, Some(&memo), |_, _, _| {}).unwrap()
    };
    let (_, first) = fit_on(&caps[..18], &train[..18], &settings);
    assert!(!first.geometry_reused, "an empty memo has nothing to give");
    let (shared, report) = fit_on(&caps, &train, &settings);
    assert!(
        report.geometry_reused,
        "the same first 12 pairs: the geometry is shared"
    );
    assert_eq!(report.loss_history, first.loss_history);
    // What a fit of its own gives.
    let (own, own_report) = fit(&caps, &train, init.clone(), &settings, |_, _, _| {}).unwrap();
    assert!(!own_report.geometry_reused);
    let (a, b) = (shared.simplify(), own.simplify());
    for c in &caps[18..] {
        let worst = max_abs(&a.apply(c), &b.apply(c));
        assert!(worst < 1e-5, "shared and own geometry differ by {worst}");
    }
    // Another lattice shares it; other first pairs, or another ridge, do not.
    let finer = FitSettings {
        lattice: Some(ImageSize::new(40, 40)),
        ..settings.clone()
    };
    assert!(fit_on(&caps, &train, &finer).1.geometry_reused);
    let (rc, rt): (Vec<CamImage>, Vec<NetImage>) = (
        caps.iter().rev().cloned().collect(),
        train.iter().rev().cloned().collect(),
    );
    assert!(!fit_on(&rc, &rt, &settings).1.geometry_reused);
    let ridge = FitSettings {
        ridge: 2.0 * settings.ridge,
        ..settings.clone()
    };
    assert!(!fit_on(&caps, &train, &ridge).1.geometry_reused);
    // The memo keeps the last geometry fitted: the reversed pairs' is gone.
    assert!(!fit_on(&rc, &rt, &settings).1.geometry_reused);
}

/// A linear fit searches its response curves on its first `geometry_images` pairs: the fit on
/// those pairs, its colour sums grown with every pair ([`ColourSums`], as a calibration grows
/// them behind its captures), is the fit on all the pairs, to the bit. The first fit need not
/// solve each pixel ([`ColourSolve::Global`], as a calibration's does): its geometry and curves
/// are the same, its coefficients one global model.
#[test]
fn a_fit_grown_from_the_geometrys_pairs_is_the_fit_on_all_of_them() {
    let [tr, _] = pairs(&System::new(), 11);
    let (train, caps): (Vec<NetImage>, Vec<CamImage>) = tr.into_iter().unzip();
    let init = Warp::from_affine([[0.8, 0.0, 0.02], [0.0, 0.83, 0.0]]);
    let settings = FitSettings {
        geometry_images: 12,
        ..settings()
    };
    let no_progress = |_: &str, _: usize, _: usize| {};
    let first_fit = |colour| {
        let s = FitSettings {
            colour,
            ..settings.clone()
        };
        fit(&caps[..12], &train[..12], init.clone(), &s, no_progress).unwrap()
    };
    let ((first, global_report), (per_pixel, _)) = (
        first_fit(ColourSolve::Global),
        first_fit(ColourSolve::PerPixel),
    );
    assert_eq!(first.curves, per_pixel.curves);
    assert_eq!(first.grid(), per_pixel.grid());
    let one = first.coeffs.data[0];
    assert!(
        first.coeffs.data.iter().all(|k| *k == one),
        "one global model"
    );
    assert!(per_pixel.coeffs.data.iter().any(|k| *k != one));
    assert!(global_report.final_loss.is_finite() && global_report.final_loss > 0.0);
    let (all, _) = fit(&caps, &train, init, &settings, no_progress).unwrap();
    assert_eq!(first.curves, all.curves, "the curves of the first 12 pairs");
    let mut sums = ColourSums::new(first.grid(), first.curves, settings.ridge);
    // In the steps a calibration's captures might come in.
    for range in [0..12, 12..13, 13..20, 20..24] {
        sums.add(&caps[range.clone()], &train[range]).unwrap();
    }
    let (grown, _) = sums.solve();
    assert_eq!(grown.data.len(), all.coeffs.data.len());
    let differ = (grown
        .data
        .iter()
        .flatten()
        .zip(all.coeffs.data.iter().flatten()))
    .filter(|(a, b)| a.to_bits() != b.to_bits())
    .count();
    assert_eq!(differ, 0, "of {} coefficients", 12 * grown.data.len());
}

/// Structured-light geometry: a known affine camera→projector map must come back as its inverse.
#[test]
fn sl_grid_inverts_a_known_correspondence() {
    use compend::patterns::Correspondence;
    use compend::raster::{Mask, Plane, Rect};
    use compend::sample::norm_to_pixel;
    use compend::slgrid::grid_from_correspondence;

    let (cw, ch) = (90usize, 70usize);
    let (pw, ph) = (64usize, 48usize);
    // Camera pixel (cx, cy) sees projector (0.8 cx − 0.1 cy − 4, 0.05 cx + 0.75 cy − 3), rounded
    // to halves as the Gray-code decoder reports them; pixels outside the projector are invalid.
    let map = |cx: f32, cy: f32| [0.8 * cx - 0.1 * cy - 4.0, 0.05 * cx + 0.75 * cy - 3.0];
    let half = |v: f32| (v * 2.0).round() / 2.0;
    let mut x = Plane::<Camera>::new(cw, ch);
    let mut y = Plane::<Camera>::new(cw, ch);
    let mut valid = Mask::<Camera>::new(cw, ch);
    for cy in 0..ch {
        for cx in 0..cw {
            let [px, py] = map(cx as f32, cy as f32);
            let (px, py) = (half(px), half(py));
            if px >= 0.0 && py >= 0.0 && px <= (pw - 1) as f32 && py <= (ph - 1) as f32 {
                x.set(cx, cy, px);
                y.set(cx, cy, py);
                valid.set(cx, cy, true);
            }
        }
    }
    let corr = Correspondence {
        projector: ImageSize::new(pw, ph),
        x,
        y,
        lit: valid.clone(),
        valid,
        contrast: Plane::new(cw, ch),
    };
    let canvas = Rect {
        x: 0,
        y: 0,
        width: pw,
        height: ph,
    };
    let (nw, nh) = (32usize, 24usize);
    let sl = grid_from_correspondence(&corr, canvas, ImageSize::new(nw, nh)).unwrap();
    assert!(
        sl.measured.count() > nw * nh * 9 / 10,
        "most of the canvas is seen"
    );
    // Invert the affine map analytically and compare at every measured network pixel.
    let (a, b, c, d) = (0.8f64, -0.1f64, 0.05f64, 0.75f64);
    let det = a * d - b * c;
    let (mut worst_inner, mut worst_border, mut sum, mut n) = (0f64, 0f64, 0f64, 0usize);
    for j in 0..nh {
        for i in 0..nw {
            if !sl.measured.get(i, j) {
                continue;
            }
            let px = i as f64 * (pw - 1) as f64 / (nw - 1) as f64 + 4.0;
            let py = j as f64 * (ph - 1) as f64 / (nh - 1) as f64 + 3.0;
            let (ex, ey) = ((d * px - b * py) / det, (-c * px + a * py) / det);
            let [gx, gy] = sl.grid.get(i, j);
            let (gx, gy) = (norm_to_pixel(gx, cw) as f64, norm_to_pixel(gy, ch) as f64);
            let e = (gx - ex).hypot(gy - ey);
            let border = i == 0 || j == 0 || i == nw - 1 || j == nh - 1;
            if border {
                worst_border = worst_border.max(e);
            } else {
                worst_inner = worst_inner.max(e);
            }
            sum += e;
            n += 1;
        }
    }
    // Decoded positions are quantised to half projector pixels (~0.6 camera px); the local fit
    // averages that out, less well on the border where the window is one-sided.
    let mean = sum / n as f64;
    assert!(mean < 0.1, "mean error {mean:.3} camera pixels");
    assert!(
        worst_inner < 0.3,
        "worst interior error {worst_inner:.3} camera pixels"
    );
    assert!(
        worst_border < 0.6,
        "worst border error {worst_border:.3} camera pixels"
    );
}

/// Saturated and black captures (an over-exposed or covered camera for some images) must not
/// crash the fit or produce non-finite coefficients.
#[test]
fn degenerate_captures_give_a_finite_model() {
    let sys = System::new();
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let train: Vec<NetImage> = (0..12).map(|_| texture(&mut rng)).collect();
    let mut caps: Vec<CamImage> = train.iter().map(|t| sys.capture(t)).collect();
    caps[0] = CamImage::filled(CAM.width, CAM.height, [1.0; 3]); // saturated
    caps[1] = CamImage::new(CAM.width, CAM.height); // black
    caps[2] = caps[2].map(|v| (v * 4.0).min(1.0)); // mostly clipped
    let init = Warp::from_affine([[0.8, 0.0, 0.02], [0.0, 0.83, 0.0]]);
    let settings = FitSettings {
        network_size: ImageSize::new(NET, NET),
        levels: vec![(NET, 20, 1.0)],
        ..FitSettings::default()
    };
    let (model, report) = fit(&caps, &train, init, &settings, |_, _, _| {}).unwrap();
    assert!(report.final_loss.is_finite());
    assert!(model.coeffs.data.iter().flatten().all(|v| v.is_finite()));
    let out = model.simplify().apply(&caps[3]);
    assert!(
        out.data()
            .iter()
            .all(|v| v.is_finite() && (0.0..=1.0).contains(v))
    );
}
