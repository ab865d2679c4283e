//! The virtual rig: determinism, physics sanity, the ordering of the reference rows, latency,
//! self-occlusion, and the `compend sim` command line.
//!
//! Submodules: `sim` (the simulator and the virtual rig through the library), `reference` (the
//! reference rows and the oracle), `sets` (sets of projectors), `cli` (the `compend sim` commands
//! and exported setups). The
//! helpers here are shared: tiny scenes (camera 80×60, projector 100×75 pixels), test images on
//! the projector canvas or in a camera-space area, and scores.

use compend::device::{DisplaySink, FrameSource};
use compend::metrics::Scores;
use compend::raster::{CamImage, Camera, ImageSize, Mask, PrjImage, Rect};
use compend::rig::{self, OracleOptions, Phase, Simulator};

mod cli;
mod reference;
mod sets;
mod sim;

/// Tiny sizes keep every test fast: camera 80×60, projector 100×75.
const CAM: ImageSize = ImageSize::new(80, 60);
const PRJ: ImageSize = ImageSize::new(100, 75);

fn tiny(name: &str, seed: u64) -> Simulator {
    let scene = rig::builtin(name)
        .expect("built-in")
        .with_resolution(CAM, PRJ);
    Simulator::new(&scene, seed, Phase::Calibration).expect("scene builds")
}

/// A smooth, colourful test image as a function of normalised canvas coordinates (u, v) in
/// [0,1]² (0 and 1 are the centres of the first and last pixels), with one sharp-edged block.
fn test_pattern(k: usize, u: f32, v: f32) -> [f32; 3] {
    let tau = std::f32::consts::TAU;
    let ph = k as f32 * 0.7;
    let mut p = [
        0.5 + 0.4 * (tau * (1.1 * u + 0.3 * v) + ph).sin(),
        0.5 + 0.4 * (tau * (0.8 * v - 0.4 * u) + 2.0 * ph).cos(),
        0.5 + 0.35 * (tau * 1.6 * (u + v) + 3.0 * ph).sin(),
    ];
    let (bx, by) = (0.2 + 0.15 * (k % 3) as f32, 0.3 + 0.1 * (k % 2) as f32);
    if u > bx && u < bx + 0.3 && v > by && v < by + 0.25 {
        p = [
            0.9 - 0.3 * (k % 2) as f32,
            0.85,
            0.2 + 0.5 * (k % 3) as f32 / 2.0,
        ];
    }
    p
}

/// Test image k stretched over the whole projector frame (the canvas).
fn on_canvas(sim: &Simulator, k: usize) -> PrjImage {
    let ImageSize {
        width: w,
        height: h,
    } = sim.projector_size();
    PrjImage::from_fn(w, h, |x, y| {
        test_pattern(k, x as f32 / (w - 1) as f32, y as f32 / (h - 1) as f32)
    })
}

/// Test image k placed in `area` of the camera view, black elsewhere.
fn in_area(sim: &Simulator, k: usize, area: Rect) -> CamImage {
    let ImageSize {
        width: w,
        height: h,
    } = sim.camera_size();
    CamImage::from_fn(w, h, |x, y| {
        if !area.contains(x, y) {
            return [0.0; 3];
        }
        let u = (x - area.x) as f32 / (area.width - 1).max(1) as f32;
        let v = (y - area.y) as f32 / (area.height - 1).max(1) as f32;
        test_pattern(k, u, v)
    })
}

/// The displayable area of the true lit region (the largest rectangle of the projector's
/// aspect inside it).
fn area_of(sim: &Simulator) -> Rect {
    let ImageSize {
        width: pw,
        height: ph,
    } = sim.projector_size();
    compend::fov::displayable_area(&sim.lit_mask(), pw as f64 / ph as f64).expect("an area")
}

fn references(sim: &Simulator, n: usize) -> rig::ReferenceScores {
    let area = area_of(sim);
    let unc: Vec<PrjImage> = (0..n).map(|k| on_canvas(sim, k)).collect();
    let des: Vec<CamImage> = (0..n).map(|k| in_area(sim, k, area)).collect();
    rig::reference_scores(
        sim,
        &unc,
        &des,
        area,
        OracleOptions::default(),
        rig::score::Frames::single(1000),
    )
    .expect("scores")
}

fn show(s: &Scores) -> String {
    format!("{:.2} dB / SSIM {:.3}", s.psnr, s.ssim)
}

mod common_cli {
    pub use crate::common::{assert_code, compend, compend_in, stderr, stdout};
}

fn mean(img: &CamImage, mask: Option<&Mask<Camera>>) -> f64 {
    let mut sum = 0.0;
    let mut n = 0usize;
    for (i, px) in img.data().chunks_exact(3).enumerate() {
        if mask.is_none_or(|m| m.data()[i]) {
            sum += px.iter().map(|&v| v as f64).sum::<f64>();
            n += 3;
        }
    }
    sum / n.max(1) as f64
}
