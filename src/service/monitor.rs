//! Monitoring during playback: the desired view of a presented frame is scored against the
//! camera's view of that same frame, in the displayable area; a score that falls more than a
//! threshold below the model's first one is drift.

use std::sync::atomic::{AtomicBool, AtomicU32, Ordering};
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
    ends_playback: bool,
    /// Consecutive checks below the baseline by more than the threshold.
    below: AtomicU32,
    drift: AtomicBool,
}

/// Consecutive checks past the threshold that make drift: one hard frame of content is not a
/// moved projector; a move is still reported within two monitoring periods.
pub(super) const CONFIRM_CHECKS: u32 = 2;

/// The run of checks past the threshold after one scoring `psnr` (dB) against `baseline`, given
/// the run before it, and whether that run is drift.
fn judge(baseline: f64, psnr: f64, threshold_db: f64, run: u32) -> (u32, bool) {
    let run = if baseline - psnr > threshold_db {
        run + 1
    } else {
        0
    };
    (run, run >= CONFIRM_CHECKS)
}

impl Tap {
    /// `ends_playback`: drift ends the playback (the engine recalibrates); otherwise it is
    /// reported and playback goes on.
    pub(super) fn new(baseline: Option<f64>, threshold_db: f64, ends_playback: bool) -> Arc<Self> {
        Arc::new(Self {
            want: Mutex::new(None),
            baseline: Mutex::new(baseline),
            threshold_db,
            ends_playback,
            below: AtomicU32::new(0),
            drift: AtomicBool::new(false),
        })
    }

    pub(super) fn baseline(&self) -> Option<f64> {
        *self.baseline.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Drift was found and it ends the playback.
    pub(super) fn ends_playback(&self) -> bool {
        self.ends_playback && self.drift.load(Ordering::Relaxed)
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
        self.below.store(0, Ordering::Relaxed);
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
        let run = self.below.load(Ordering::Relaxed);
        let (run, drift) = judge(baseline, s.psnr, self.threshold_db, run);
        self.below.store(run, Ordering::Relaxed);
        tracing::info!(
            "monitoring: frame {seq}: {:.2} dB / SSIM {:.3} in the displayable area (baseline \
             {baseline:.2} dB){}",
            s.psnr,
            s.ssim,
            match (drift, run) {
                (true, _) => "; DRIFT".to_string(),
                (false, 0) => String::new(),
                (false, n) =>
                    format!("; below by more than the threshold ({n} of {CONFIRM_CHECKS})"),
            }
        );
        if drift && !self.drift.swap(true, Ordering::Relaxed) {
            tracing::warn!(
                "drift: the compensated projection scores {:.2} dB, {:.2} dB below the {:.2} dB \
                 measured after installation ({CONFIRM_CHECKS} checks in a row past the \
                 threshold of {:.2} dB)",
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn drift_needs_consecutive_checks_past_the_threshold() {
        // baseline 30 dB, threshold 3 dB.
        let mut run = 0;
        let mut drifts = Vec::new();
        for psnr in [29.0, 26.5, 29.5, 26.9, 26.0, 25.0, 29.0] {
            let (r, d) = judge(30.0, psnr, 3.0, run);
            run = r;
            drifts.push(d);
        }
        // One hard frame (26.5) is not drift; two in a row (26.9, 26.0) are, and so on until a
        // check comes back within the threshold.
        assert_eq!(drifts, [false, false, false, false, true, true, false]);
        // Exactly at the threshold is not past it.
        assert_eq!(judge(30.0, 27.0, 3.0, 1), (0, false));
    }
}
