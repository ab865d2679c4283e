//! The frame budget of a climb: a CompenNet++ rung is only worth climbing to if the GPU that is
//! to play it can run its pass at the display's refresh rate. The core cannot time a GPU pass,
//! so the caller that knows the display hands `auto` a [`LivePass`] (the GPU shell's
//! [`crate::gpu::live::GpuLivePass`]); `auto` describes the pass it would play
//! ([`PassShape`]) and skips the climb when the measured time does not fit
//! ([`LiveCost::fits`]).

use std::fmt::Debug;

use crate::error::Result;
use crate::model::Method;
pub use crate::model::store::{LIVE_SHARE, LiveCost};
use crate::raster::ImageSize;

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

/// Times a rung's live pass where it is to play, against that display's refresh.
pub trait LivePass: Send + Sync + Debug {
    /// The median time of one frame of the pass of `shape`, with the display's budget.
    fn cost(&self, shape: &PassShape) -> Result<LiveCost>;
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_pass_fits_half_of_one_refresh_period() {
        let at = |ms: f64, hz: f64| {
            LiveCost::new(
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
