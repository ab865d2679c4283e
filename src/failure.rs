//! How a trained model fails, when it does: the classification `compend bench` reports and
//! calibration checks before it installs anything (docs/architecture.md, "Models").
//!
//! - **diverged**: an output or a score is not a number (the training blew up);
//! - **collapsed**: the outputs hardly depend on the input, e.g. flat gray whatever is asked:
//!   across several different inputs they vary less than [`COLLAPSE_RATIO`] as much as the
//!   inputs do;
//! - **worse than uncompensated**: the compensated projection scores a lower PSNR than the
//!   images projected as they are.
//!
//! Pure: it reads images and scores, whatever produced them.

use serde::{Deserialize, Serialize};

use crate::raster::{Rgb, Space};

/// Outputs varying less than this fraction of the inputs' variation (the mean per-value
/// standard deviation across images) count as collapsed. A working model's outputs vary about
/// as much as its inputs or more (it stretches contrast where the surface is dark).
pub const COLLAPSE_RATIO: f64 = 0.1;

/// A failed model, by kind.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Failure {
    Diverged,
    Collapsed,
    WorseThanUncompensated,
}

impl Failure {
    pub fn name(self) -> &'static str {
        match self {
            Failure::Diverged => "diverged",
            Failure::Collapsed => "collapsed",
            Failure::WorseThanUncompensated => "worse than uncompensated",
        }
    }

    /// What it means, for a person.
    pub fn explain(self) -> &'static str {
        match self {
            Failure::Diverged => {
                "the model's outputs or scores are not numbers: its training diverged"
            }
            Failure::Collapsed => {
                "the model gives nearly the same image whatever it is asked to show: it \
                 collapsed (to flat gray, or to one picture)"
            }
            Failure::WorseThanUncompensated => {
                "the compensated projection looks worse than the images projected as they are"
            }
        }
    }
}

impl std::fmt::Display for Failure {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// The mean over values of the standard deviation across `images` (all the same size), in the
/// images' own units; 0 for fewer than two images.
pub fn spread<S: Space>(images: &[&Rgb<S>]) -> f64 {
    let n = images.len();
    let Some(first) = images.first() else {
        return 0.0;
    };
    let len = first.data().len();
    if n < 2 || len == 0 || images.iter().any(|i| i.data().len() != len) {
        return 0.0;
    }
    let mut total = 0.0;
    for k in 0..len {
        let mean = images.iter().map(|i| i.data()[k] as f64).sum::<f64>() / n as f64;
        let var = images
            .iter()
            .map(|i| (i.data()[k] as f64 - mean).powi(2))
            .sum::<f64>()
            / (n - 1) as f64;
        total += var.sqrt();
    }
    total / len as f64
}

/// Classifies a model from its `outputs` for several `inputs` (any spaces and sizes: only
/// their spreads are compared) and the PSNR (dB) of the compensated and the uncompensated
/// projection of the same images. `None`: no failure found.
pub fn classify<A: Space, B: Space>(
    inputs: &[&Rgb<A>],
    outputs: &[&Rgb<B>],
    compensated_psnr: f64,
    uncompensated_psnr: f64,
) -> Option<Failure> {
    let finite = outputs
        .iter()
        .all(|o| o.data().iter().all(|v| v.is_finite()));
    if !finite || !compensated_psnr.is_finite() {
        return Some(Failure::Diverged);
    }
    let wanted = spread(inputs);
    if outputs.len() >= 2 && wanted > 0.0 && spread(outputs) < COLLAPSE_RATIO * wanted {
        return Some(Failure::Collapsed);
    }
    if compensated_psnr < uncompensated_psnr {
        return Some(Failure::WorseThanUncompensated);
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::raster::{CamImage, NetImage};

    #[test]
    fn failures_are_told_apart_and_a_working_model_passes() {
        let inputs: Vec<CamImage> = (0..3)
            .map(|i| CamImage::filled(4, 4, [0.2 + 0.3 * i as f32; 3]))
            .collect();
        let ins: Vec<&CamImage> = inputs.iter().collect();
        // Outputs that follow the inputs (stretched): fine, unless they score below the
        // uncompensated projection.
        let good: Vec<NetImage> = (0..3)
            .map(|i| NetImage::filled(2, 2, [0.1 + 0.4 * i as f32; 3]))
            .collect();
        let good: Vec<&NetImage> = good.iter().collect();
        assert_eq!(classify(&ins, &good, 28.0, 20.0), None);
        assert_eq!(
            classify(&ins, &good, 19.0, 20.0),
            Some(Failure::WorseThanUncompensated)
        );
        // The same gray whatever the input: collapsed, even with a good score.
        let gray = NetImage::filled(2, 2, [0.5; 3]);
        assert_eq!(
            classify(&ins, &[&gray, &gray, &gray], 28.0, 20.0),
            Some(Failure::Collapsed)
        );
        // A NaN anywhere, or a score that is not a number: diverged.
        let mut bad = NetImage::filled(2, 2, [0.5; 3]);
        bad.set(1, 1, [f32::NAN, 0.0, 0.0]);
        assert_eq!(
            classify(&ins, &[good[0], &bad, good[2]], 28.0, 20.0),
            Some(Failure::Diverged)
        );
        assert_eq!(
            classify(&ins, &good, f64::NAN, 20.0),
            Some(Failure::Diverged)
        );
        assert!((spread(&ins) - 0.3).abs() < 1e-6, "{}", spread(&ins));
        assert_eq!(spread::<crate::raster::Camera>(&[]), 0.0);
    }
}
