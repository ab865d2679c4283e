//! The frame budget of a climb: a CompenNet++ rung is only worth climbing to if the GPU that is
//! to play it can run its pass at the display's refresh rate. The core cannot time a GPU pass,
//! so the caller that knows the display hands `auto` a [`LivePass`] (the GPU shell's
//! [`crate::gpu::live::GpuLivePass`]); `auto` describes the pass it would play
//! ([`PassShape`]) and skips the climb when the measured time does not fit
//! ([`LiveCost::fits`]).

use std::fmt::Debug;

use crate::error::Result;
use crate::model::Method;
use crate::raster::ImageSize;
pub use crate::record::LiveCost;

/// The share of one refresh period the compensation pass may take: the rest is left to the
/// content's upload, the copy into the window's surface and the compositor.
pub const LIVE_SHARE: f64 = 0.5;

/// A pass measured at `pass_ms` per frame, weighed against the budget of a display refreshing
/// at `refresh_hz`: [`LIVE_SHARE`] of one refresh period.
pub fn budgeted(
    method: Method,
    adapter: String,
    projector: ImageSize,
    pass_ms: f64,
    refresh_hz: f64,
) -> LiveCost {
    LiveCost {
        method,
        adapter,
        projector,
        pass_ms,
        refresh_hz,
        budget_ms: LIVE_SHARE * 1e3 / refresh_hz,
    }
}

/// The shapes of the pass a rung would play with, as training would make it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PassShape {
    /// The rung (a residual rung: its `linear` part and its correction).
    pub method: Method,
    /// The desired view's size, camera pixels.
    pub camera: ImageSize,
    /// The output lattice of a linear rung or of a residual rung's `linear` part, network
    /// pixels (unused by the other CompenNet++ rungs).
    pub lattice: ImageSize,
    /// The data root's network size, network pixels (a CompenNet++ rung's network, or a
    /// residual rung's correction network, is this divided by the variant's divisor).
    pub network: ImageSize,
    /// The projector frame the pass writes, projector pixels.
    pub projector: ImageSize,
}

/// What is wrong with `hz` as the rate a climb's live pass is weighed at (`--refresh-hz`, the
/// configuration's `refresh_hz`): `None` for a positive rate or 0 (not weighed). Rates no
/// display has are taken: far ones (1e-3 Hz, 1e9 Hz) decide a climb whatever the GPU, which
/// the tests use.
pub fn refresh_rate_problem(hz: f64) -> Option<String> {
    if hz.is_finite() && hz >= 0.0 {
        return None;
    }
    // 5e-324 as such, not as 324 digits.
    let shown = if hz.is_finite() && !(1e-3..1e6).contains(&hz.abs()) {
        format!("{hz:e}")
    } else {
        format!("{hz}")
    };
    Some(format!(
        "{shown}: expected a refresh rate in Hz, or 0 (a climb's live pass not weighed)"
    ))
}

/// Times a rung's live pass where it is to play, against that display's refresh.
pub trait LivePass: Send + Sync + Debug {
    /// The median time of one frame of the pass of `shape`, with the display's budget.
    fn cost(&self, shape: &PassShape) -> Result<LiveCost>;
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_refresh_rate_is_a_positive_rate_or_0() {
        for ok in [0.0, 1e-3, 23.976, 60.0, 1e9] {
            assert_eq!(refresh_rate_problem(ok), None, "{ok}");
        }
        for bad in [
            -60.0,
            -5e-324,
            -1e308,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NAN,
        ] {
            let e = refresh_rate_problem(bad).expect("refused");
            assert!(e.contains("expected a refresh rate in Hz, or 0"), "{e}");
            assert!(e.len() < 150, "{e}");
        }
    }

    #[test]
    fn a_pass_fits_half_of_one_refresh_period() {
        let at = |ms: f64, hz: f64| {
            budgeted(
                Method::CompenNetPpRes,
                "test".into(),
                ImageSize::new(1920, 1080),
                ms,
                hz,
            )
        };
        // 60 Hz: 16.7 ms per refresh, 8.3 ms for the pass.
        assert!((at(1.0, 60.0).budget_ms - 8.333).abs() < 1e-3);
        assert!(at(8.3, 60.0).fits());
        assert!(!at(8.4, 60.0).fits());
        assert!(at(8.4, 50.0).fits());
        assert!(!at(f64::NAN, 60.0).fits());
        assert!(!at(f64::INFINITY, 60.0).fits());
        let words = at(12.0, 60.0).describe();
        assert!(
            words.contains(
                "12.00 ms per 1920x1080 frame on test, over the 8.33 ms budget (half of one \
                 refresh period at 60.00 Hz)"
            ),
            "{words}"
        );
        // Rates far from a display's are written in few digits.
        let words = at(1.0, 1e-300).describe();
        assert!(words.contains("within the 5.00e302 ms budget"), "{words}");
        assert!(words.contains("at 1.00e-300 Hz"), "{words}");
    }
}
