//! Monitoring during playback: the desired view of a presented frame is scored against the
//! camera's view of that same frame, in the displayable area; a score that falls more than a
//! threshold below the model's first one is drift.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};

use super::Shared;
use crate::error::Result;
use crate::metrics::Accumulator;
use crate::raster::{CamImage, Rect};

/// Monitoring: the desired view of one presented frame waits here for the camera's view of it;
/// the two are scored in the displayable area (camera pixels, encoded values).
pub(super) struct Tap {
    /// The frame asked for: its sequence number, desired view and displayable area (camera
    /// pixels; the area of the pass that showed it).
    want: Mutex<Option<(u64, CamImage, Rect)>>,
    baseline: Mutex<Option<f64>>,
    threshold_db: f64,
    drift: AtomicBool,
}

impl Tap {
    pub(super) fn new(baseline: Option<f64>, threshold_db: f64) -> Arc<Self> {
        Arc::new(Self {
            want: Mutex::new(None),
            baseline: Mutex::new(baseline),
            threshold_db,
            drift: AtomicBool::new(false),
        })
    }

    pub(super) fn baseline(&self) -> Option<f64> {
        *self.baseline.lock().unwrap_or_else(|e| e.into_inner())
    }

    pub(super) fn drifted(&self) -> bool {
        self.drift.load(Ordering::Relaxed)
    }

    /// Asks for the camera's view of frame `seq`, whose desired view is `desired`, to be scored
    /// in `area`.
    pub(super) fn request(&self, seq: u64, desired: CamImage, area: Rect) {
        *self.want.lock().unwrap_or_else(|e| e.into_inner()) = Some((seq, desired, area));
    }

    /// Another model plays from now on: its first score is the new baseline, and a drift of the
    /// old one is forgotten.
    pub(super) fn reset(&self) {
        *self.baseline.lock().unwrap_or_else(|e| e.into_inner()) = None;
        *self.want.lock().unwrap_or_else(|e| e.into_inner()) = None;
        self.drift.store(false, Ordering::Relaxed);
    }

    /// A camera view of frame `seq`: scored if it is the one asked for.
    pub(super) fn offer(&self, seq: u64, view: &CamImage, shared: &Shared) {
        let desired = {
            let mut want = self.want.lock().unwrap_or_else(|e| e.into_inner());
            match &*want {
                Some((s, _, _)) if *s == seq => want.take().map(|(_, d, a)| (d, a)),
                // The asked-for view was skipped: ask again at the next period.
                Some((s, _, _)) if *s < seq => {
                    *want = None;
                    None
                }
                _ => None,
            }
        };
        let Some((desired, area)) = desired else {
            return;
        };
        let scored = (|| -> Result<crate::metrics::Scores> {
            let mut acc = Accumulator::default();
            acc.add(&view.crop(area)?, &desired.crop(area)?)?;
            acc.finish()
        })();
        let s = match scored {
            Ok(s) => s,
            Err(e) => {
                tracing::warn!("monitoring: frame {seq} could not be scored: {e}");
                return;
            }
        };
        let baseline = {
            let mut b = self.baseline.lock().unwrap_or_else(|e| e.into_inner());
            *b.get_or_insert(s.psnr)
        };
        let drift = baseline - s.psnr > self.threshold_db;
        tracing::info!(
            "monitoring: frame {seq}: {:.2} dB / SSIM {:.3} in the displayable area (baseline \
             {baseline:.2} dB){}",
            s.psnr,
            s.ssim,
            if drift { "; DRIFT" } else { "" }
        );
        if drift && !self.drift.swap(true, Ordering::Relaxed) {
            tracing::warn!(
                "drift: the compensated projection scores {:.2} dB, {:.2} dB below the {:.2} dB \
                 measured after installation (threshold {:.2} dB)",
                s.psnr,
                baseline - s.psnr,
                baseline,
                self.threshold_db
            );
        }
        shared.update(|st| {
            let m = &mut st.monitoring;
            m.checks += 1;
            m.psnr = Some(s.psnr);
            m.ssim = Some(s.ssim);
            m.baseline_psnr = Some(baseline);
            m.age_s = Some(0.0);
            if drift && !m.drift {
                m.drifts += 1;
            }
            m.drift = drift;
        });
    }
}
