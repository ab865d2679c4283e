//! Monitoring during playback: the desired view of a presented frame is scored against the
//! camera's view of that same frame, in the displayable area; a score that falls more than a
//! threshold below the model's first one is drift.
//!
//! On the virtual rig the camera sees every presented frame by construction. A real camera (or
//! the window rig's) streams on its own clock, a latency behind the projector: [`Sighting`]
//! tells which presented content a camera frame saw alone, by the rule of the capture protocol
//! ([`crate::calibrate::sync`]), and content that changes faster than the latency is never
//! scored (the check is counted as unseen).

use std::collections::VecDeque;
use std::sync::atomic::{AtomicBool, AtomicU32, Ordering};
use std::sync::mpsc::Receiver;
use std::sync::{Arc, Mutex};
use std::time::Instant;

use super::Shared;
use crate::calibrate::clock::{CameraClock, ClockFinder};
use crate::device::{Frame, FrameSource};
use crate::error::Result;
use crate::metrics::Accumulator;
use crate::raster::{CamImage, Camera, Mask, Rect};

/// Where a seam between a set's pictures would show in the camera's view (camera pixels): the
/// band along the projectors' overlap edges and the pixels away from them, inside the set's
/// displayable area ([`crate::joint::seam_regions`]). Each check's seam figure
/// ([`crate::metrics::seam_figure`]) compares the camera's error in the one with the other.
pub(super) struct SeamBands {
    band: Mask<Camera>,
    away: Mask<Camera>,
    /// The largest ratio that passes ([`crate::calibrate::set::SEAM_LIMIT`]).
    limit: f64,
}

/// What monitoring watches of a set of projectors beyond the whole: the seam bands where its
/// pictures overlap, and each projector's part of the displayable area (camera pixels: where it
/// lights inside the area), scored on its own.
pub(super) struct SetWatch {
    pub(super) seam: Option<SeamBands>,
    pub(super) parts: Vec<Mask<Camera>>,
}

impl SetWatch {
    /// The set whose projectors light `covers` (camera pixels), in its displayable `area`.
    pub(super) fn of(covers: &[Mask<Camera>], area: Rect, seam_limit: f64) -> Self {
        let parts = covers
            .iter()
            .map(|c| {
                let size = c.size();
                Mask::from_fn(size.width, size.height, |x, y| {
                    c.get(x, y)
                        && x >= area.x
                        && x < area.x + area.width
                        && y >= area.y
                        && y < area.y + area.height
                })
            })
            .collect();
        Self {
            seam: SeamBands::of(covers, area, seam_limit),
            parts,
        }
    }
}

impl SeamBands {
    /// The bands of the projectors lighting `covers` (camera pixels) inside `area`; `None`
    /// where no two overlap (a tiled set without a blend, or nothing away from the edges).
    pub(super) fn of(covers: &[Mask<Camera>], area: Rect, limit: f64) -> Option<Self> {
        let (band, away) = crate::joint::seam::seam_bands(covers, area, covers.first()?.size())?;
        Some(Self { band, away, limit })
    }
}

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
    /// A set's seam bands and parts: each check's seam figure and each projector's score too.
    set: Option<SetWatch>,
    /// The first check's seam ratio.
    seam_baseline: Mutex<Option<f64>>,
    /// A seam was said in the log (and is said again when it is gone).
    seam_said: AtomicBool,
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
    /// `set`: a set's seam bands and parts, whose figures each check gives as well.
    pub(super) fn new(
        baseline: Option<f64>,
        threshold_db: f64,
        ends_playback: bool,
        set: Option<SetWatch>,
    ) -> Arc<Self> {
        Arc::new(Self {
            want: Mutex::new(None),
            baseline: Mutex::new(baseline),
            threshold_db,
            ends_playback,
            below: AtomicU32::new(0),
            drift: AtomicBool::new(false),
            set,
            seam_baseline: Mutex::new(None),
            seam_said: AtomicBool::new(false),
        })
    }

    /// The seam ratio of the camera's `view` against `desired` ([`crate::metrics::SeamFigure::ratio`])
    /// for a set whose pictures overlap, and its baseline (the first check's: the figure depends
    /// on the content, whose own edges may lie along the overlap). A seam that was not there at
    /// the baseline and passes the verification's limit is said in the log, and when it is
    /// gone again.
    fn seam_ratio(&self, seq: u64, view: &CamImage, desired: &CamImage) -> Option<(f64, f64)> {
        let b = self.set.as_ref()?.seam.as_ref()?;
        let ratio = match crate::metrics::seam_figure(view, desired, b.band.data(), b.away.data()) {
            Ok(f) => f.ratio(),
            Err(e) => {
                tracing::warn!("monitoring: frame {seq}: no seam figure: {e}");
                return None;
            }
        };
        let baseline = *self
            .seam_baseline
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .get_or_insert(ratio);
        let shows = ratio > b.limit && baseline <= b.limit;
        if shows != self.seam_said.swap(shows, Ordering::Relaxed) {
            if shows {
                tracing::warn!(
                    "monitoring: a seam shows: the error along the overlap edges is {ratio:.2} \
                     times the error away from them, {baseline:.2} when this playback began (at \
                     most {:.2} passes verification); a projector may have moved or dimmed",
                    b.limit
                );
            } else {
                tracing::info!("monitoring: the seam is gone (ratio {ratio:.2})");
            }
        }
        Some((ratio, baseline))
    }

    /// Each projector's score in its own part of a set's area, dB (`None` for a part it does
    /// not light); empty for one projector.
    fn parts_psnr(&self, seq: u64, view: &CamImage, desired: &CamImage) -> Vec<Option<f64>> {
        let Some(set) = &self.set else {
            return Vec::new();
        };
        set.parts
            .iter()
            .map(
                |p| match crate::metrics::masked_mse(view, desired, p.data()) {
                    Ok(mse) => mse.map(crate::metrics::psnr_from_mse),
                    Err(e) => {
                        tracing::warn!(
                            "monitoring: frame {seq}: a projector's part not scored: {e}"
                        );
                        None
                    }
                },
            )
            .collect()
    }

    pub(super) fn baseline(&self) -> Option<f64> {
        *self.baseline.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Drift was found and it ends the playback.
    pub(super) fn ends_playback(&self) -> bool {
        self.ends_playback && self.drift.load(Ordering::Relaxed)
    }

    /// Asks for the camera's view of frame `seq`, whose desired view is `desired`, to be scored
    /// in `area`. A check still waiting for its view is given up (counted as unseen).
    pub(super) fn request(&self, seq: u64, desired: CamImage, area: Rect, shared: &Shared) {
        let old = self
            .want
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .replace((seq, desired, area));
        if let Some((old, _, _)) = old {
            unseen(old, shared);
        }
    }

    /// The frame whose view a check waits for.
    pub(super) fn wanted(&self) -> Option<u64> {
        self.want
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .as_ref()
            .map(|(s, _, _)| *s)
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
                    unseen(*s, shared);
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
        shared.views.set_pair(&desired, view, area);
        let seam = self.seam_ratio(seq, view, &desired);
        let parts = self.parts_psnr(seq, view, &desired);
        let baseline = {
            let mut b = self.baseline.lock().unwrap_or_else(|e| e.into_inner());
            *b.get_or_insert(s.psnr)
        };
        let run = self.below.load(Ordering::Relaxed);
        let (run, drift) = judge(baseline, s.psnr, self.threshold_db, run);
        self.below.store(run, Ordering::Relaxed);
        tracing::info!(
            "monitoring: frame {seq}: {:.2} dB / SSIM {:.3} in the displayable area (baseline \
             {baseline:.2} dB){}{}{}",
            s.psnr,
            s.ssim,
            if parts.is_empty() {
                String::new()
            } else {
                let each: Vec<String> = parts
                    .iter()
                    .map(|p| p.map_or("-".to_string(), |p| format!("{p:.2}")))
                    .collect();
                format!(", each projector's part {} dB", each.join(" / "))
            },
            seam.map_or(String::new(), |(r, b)| format!(
                ", seam ratio {r:.2} (baseline {b:.2})"
            )),
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
            m.seam_ratio = seam.map(|(r, _)| r);
            m.projectors_psnr = parts;
            m.seam_baseline = seam.map(|(_, b)| b);
            m.age_s = Some(0.0);
            if drift && !m.drift {
                m.drifts += 1;
            }
            m.drift = drift;
        });
    }
}

/// A check whose frame the camera never saw alone: counted in the status, and said in the log
/// the first time (at debug level after that).
fn unseen(seq: u64, shared: &Shared) {
    let mut first = false;
    shared.update(|st| {
        st.monitoring.unseen += 1;
        first = st.monitoring.unseen == 1;
    });
    if first {
        tracing::warn!(
            "monitoring: frame {seq} was not seen alone by the camera (the content changed, or \
             frames were dropped, before the projector-to-camera latency had passed); checks \
             score only content that stays up that long, and `status` counts the others as \
             unseen"
        );
    } else {
        tracing::debug!("monitoring: frame {seq} was not seen alone by the camera");
    }
}

/// Which presented content a camera frame saw alone, from the order of content changes and
/// exposures; the rule of the capture protocol ([`crate::calibrate::sync`]): after content
/// first presented at T, the first exposure that began at or after T has sequence number s1,
/// and exposures from s1 + `settle` on show that content (settle: the worst projector-to-camera
/// latency measured at calibration plus a margin, in exposures), as long as the next change
/// came after the exposure ended.
///
/// Times are this machine's ([`std::time::Instant`]); an exposure's start is an estimate never
/// earlier than the real one ([`crate::calibrate::clock::CameraClock::exposed_at`]).
#[derive(Debug)]
pub(super) struct Sighting {
    settle: u64,
    /// Content changes no exposure began after yet: (first frame of the content, when it was
    /// presented).
    pending: VecDeque<(u64, Instant)>,
    /// The latest content some exposure began after: (its first frame, that exposure's
    /// sequence number s1).
    current: Option<(u64, u64)>,
}

impl Sighting {
    pub(super) fn new(settle: u64) -> Self {
        Self {
            settle,
            pending: VecDeque::new(),
            current: None,
        }
    }

    /// New content, first shown as frame `seq`, was presented at `at` (in order).
    pub(super) fn changed(&mut self, seq: u64, at: Instant) {
        self.pending.push_back((seq, at));
    }

    /// The camera frame `cam_seq`, whose exposure began at `began` and ended by `ended`
    /// (estimates: never earlier than the real times), judged once every change presented
    /// before `ended` is known: the first frame of the content it saw alone, if any.
    pub(super) fn saw(&mut self, cam_seq: u64, began: Instant, ended: Instant) -> Option<u64> {
        while let Some(&(seq, at)) = self.pending.front()
            && at <= began
        {
            self.pending.pop_front();
            self.current = Some((seq, cam_seq));
        }
        let (seq, s1) = self.current?;
        if cam_seq < s1.saturating_add(self.settle) {
            return None;
        }
        // Content presented before the exposure ended may have reached the surface during it.
        if self.pending.front().is_some_and(|&(_, at)| at <= ended) {
            return None;
        }
        Some(seq)
    }
}

/// Frames grabbed while looking for the camera's clock before giving up on it (a camera whose
/// clock does not run in real time): exposures are then placed at their arrival instead.
const CLOCK_FRAMES: usize = 60;

/// Watches a camera that streams on its own clock (a V4L2 camera, the window rig's) during a
/// playback: grabs every frame, tells which content it saw alone ([`Sighting`], `settle`
/// exposures of latency) from the content changes the screen sends (first frame of the
/// content, when it was presented), and offers those views to `tap`. Ends when `stop` is set,
/// or when the camera fails and cannot be reopened: playback goes on without monitoring, as
/// the log says.
pub(super) fn watch_camera<C: FrameSource + ?Sized>(
    camera: &mut C,
    changes: Receiver<(u64, Instant)>,
    settle: u64,
    (tap, shared): (&Tap, &Shared),
    stop: &AtomicBool,
) {
    let mut sighting = Sighting::new(settle);
    let mut finder = Some(ClockFinder::new());
    let mut clock: Option<CameraClock> = None;
    // The last frame grabbed, with when its exposure began and by when it ended (its
    // arrival), judged once the next one is in: by then every change presented before it ended
    // has been sent.
    let mut held: Option<(Frame, Instant, Instant)> = None;
    while !stop.load(Ordering::Relaxed) {
        let frame = match camera.grab() {
            Ok(f) => f,
            Err(_) if stop.load(Ordering::Relaxed) => break,
            Err(e) => match camera.reconnect() {
                Ok(true) => {
                    tracing::warn!("monitoring: the camera came back after: {e}");
                    // A reopened camera may count and stamp its frames afresh.
                    (finder, clock, held) = (Some(ClockFinder::new()), None, None);
                    continue;
                }
                Ok(false) => {
                    tracing::warn!("monitoring stops for this playback: the camera failed: {e}");
                    break;
                }
                Err(again) => {
                    tracing::warn!(
                        "monitoring stops for this playback: the camera failed ({e}) and could \
                         not be reopened: {again}"
                    );
                    break;
                }
            },
        };
        let arrival = Instant::now();
        shared.views.offer_camera(&frame.image);
        if let Some(c) = &mut clock {
            c.observe(&frame, arrival);
        } else if let Some(f) = &mut finder {
            f.observe(&frame, arrival);
            clock = f.clock();
            if clock.is_some() || f.frames() >= CLOCK_FRAMES {
                finder = None;
            }
        }
        let began = clock.map_or(arrival, |c| c.exposed_at(&frame).min(arrival));
        while let Ok((seq, at)) = changes.try_recv() {
            sighting.changed(seq, at);
        }
        if let Some((f, began, ended)) = held.take()
            && let Some(seq) = sighting.saw(f.seq, began, ended)
        {
            tap.offer(seq, &f.image, shared);
        }
        held = Some((frame, began, arrival));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_camera_frame_sees_content_alone_only_after_the_latency_and_before_the_next_change() {
        let t0 = Instant::now();
        let ms = |n: u64| t0 + std::time::Duration::from_millis(n);
        // Exposures every 10 ms from 0 ms (camera frame k begins at 10k ms and ends by
        // 10k + 20 ms), settle 3 exposures.
        let mut s = Sighting::new(3);
        let judge = |s: &mut Sighting, k: u64| s.saw(k, ms(10 * k), ms(10 * k + 20));
        assert_eq!(judge(&mut s, 0), None, "nothing presented yet");
        // Content A from frame 7, presented at 15 ms: the first exposure after it is k = 2.
        s.changed(7, ms(15));
        assert_eq!(judge(&mut s, 1), None);
        assert_eq!(judge(&mut s, 2), None);
        assert_eq!(judge(&mut s, 4), None, "within the latency");
        assert_eq!(judge(&mut s, 5), Some(7));
        // Content B from frame 9 at 95 ms: exposure 8 (80..100 ms) may have seen it; 7 not.
        s.changed(9, ms(95));
        assert_eq!(judge(&mut s, 7), Some(7));
        assert_eq!(
            judge(&mut s, 8),
            None,
            "the next change came during the exposure"
        );
        // B: s1 = 10 (the first exposure beginning at or after 95 ms), seen alone from 13.
        assert_eq!(judge(&mut s, 10), None);
        assert_eq!(judge(&mut s, 12), None);
        assert_eq!(judge(&mut s, 13), Some(9));
        // Content changing every exposure is never seen alone.
        for k in 14..30 {
            s.changed(100 + k, ms(10 * k + 5));
            assert_eq!(judge(&mut s, k), None, "exposure {k}");
        }
        // Two changes before one exposure: the later one counts, from that exposure.
        s.changed(200, ms(301));
        s.changed(201, ms(302));
        assert_eq!(judge(&mut s, 31), None);
        assert_eq!(judge(&mut s, 33), None);
        assert_eq!(judge(&mut s, 34), Some(201));
    }

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
