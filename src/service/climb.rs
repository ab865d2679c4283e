//! Progressive calibration: once a calibration has installed its model and playback has
//! started, the next rung (`[calibration] climb`) trains on a thread of its own on the same
//! captures, on every pair (a residual rung's correction on the closed-loop ones), as it
//! trains alone. Its paper-protocol figures on the calibration's held-out test pairs are
//! recorded beside the installed model's, but they do not decide: held-out pairs do not tell
//! what the rig shows (docs/bench/ladder.md, "The rig judges the climb"). The trained rung is a
//! [`Candidate`]: the playback ends, the engine projects the verification images compensated by
//! both models ([`crate::calibrate::verify_after`]), and [`settle`] installs the candidate (the
//! atomic model-directory swap) only if it beats the installed model there by `climb_gain_db`
//! in closed loop ([`fit::ClimbRule::confirms`], the rule of `calibrate --method auto`);
//! playback then resumes with the model installed. The viewer sees the cheap rung within a
//! minute, and the better one when, and only if, it is better where it counts: on the surface.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, mpsc};
use std::time::Instant;

use crate::dataset::Setup;
use crate::error::{Error, Result};
use crate::fit;
use crate::model::{Method, MethodChoice, Model};
use crate::record::{ClimbClosedLoop, ClimbRecord, Verification};

/// The right to replace the installed model directory: the engine holds the only one, and a
/// calibration's install ([`Installer::install`]) and a climb's ([`settle`]) each take it by
/// `&mut`, so two installs never overlap, with no lock and no global.
pub(super) struct Installer(());

impl Installer {
    /// The engine's, made once when it starts.
    pub(super) fn new() -> Self {
        Installer(())
    }

    /// Installs a verified calibration's model into `out` ([`crate::calibrate::install`]).
    pub(super) fn install(
        &mut self,
        done: crate::calibrate::Calibrated,
        out: &Path,
    ) -> Result<Model> {
        crate::calibrate::install(done, out)
    }

    /// Installs a verified set's model into `out` ([`crate::calibrate::set::install_set`]).
    pub(super) fn install_set(
        &mut self,
        done: crate::calibrate::set::CalibratedSet,
        out: &Path,
    ) -> Result<crate::model::set::SetModel> {
        crate::calibrate::set::install_set(done, out)
    }
}

/// What to climb to, after which calibration.
#[derive(Clone, Debug)]
pub(super) struct Plan {
    pub(super) method: Method,
    pub(super) iters: Option<usize>,
    /// Where it trains (`[calibration] device`).
    pub(super) device: crate::fit::TrainDevice,
    pub(super) gain_db: f64,
    /// The calibration's data root and its setup.
    pub(super) root: PathBuf,
    pub(super) setup: PathBuf,
    /// The installed model directory: what the climb must beat, and where it installs.
    pub(super) model: PathBuf,
}

impl Plan {
    /// The climb `[calibration]` (`c`) asks for once a calibration has installed a model of
    /// `installed` into `model`, from the data root `root` and its setup `setup`: `None` when it
    /// asks for none, or for the rung just installed.
    pub(super) fn after_install(
        c: &crate::config::CalibrationConfig,
        installed: Method,
        root: &Path,
        setup: PathBuf,
        model: &Path,
    ) -> Option<Self> {
        c.climb.filter(|m| *m != installed).map(|method| Plan {
            method,
            iters: c.climb_iters,
            device: c.device,
            gain_db: c.climb_gain_db,
            root: root.to_path_buf(),
            setup,
            model: model.to_path_buf(),
        })
    }

    /// The rung's live pass timed by `probe` on the playback GPU, in the shapes the climb
    /// would give it (the installed model's camera size and lattice, the setup's network size,
    /// `projector`); `Ok(None)` when not weighed: no probe, or a linear rung, which plays at
    /// the installed one's cost. Run on the engine's thread before the playback starts, so
    /// that it times the pass alone.
    pub(super) fn live_cost(
        &self,
        probe: Option<&dyn fit::LivePass>,
        projector: crate::raster::ImageSize,
    ) -> Result<Option<crate::record::LiveCost>> {
        let Some(probe) = probe.filter(|_| !self.method.is_linear()) else {
            return Ok(None);
        };
        let setup = Setup::open(&self.setup, Some(&self.root))?;
        let installed = crate::model::store::load_meta(&self.model)?;
        probe
            .cost(&fit::PassShape {
                method: self.method,
                camera: installed.camera_size,
                lattice: installed.network_size,
                network: setup.root().network_size()?,
                projector,
            })
            .map(Some)
    }
}

/// A climbed model, trained, waiting for the rig to compare it with the installed one.
pub(super) struct Candidate {
    pub(super) plan: Plan,
    /// The climbed model, its record (`calibration.climb`) holding the held-out figures.
    pub(super) model: Model,
    /// The model it would replace, as loaded when the climb began.
    pub(super) installed: Model,
    /// Seconds from the start of the climb to the end of its judgement on the held-out pairs.
    pub(super) seconds: f64,
}

/// A climb under way.
pub(super) struct Climb {
    pub(super) plan: Plan,
    started: Instant,
    cancel: Arc<AtomicBool>,
    result: mpsc::Receiver<Result<Box<Candidate>>>,
}

impl Climb {
    /// Starts training `plan.method`.
    pub(super) fn start(plan: Plan) -> Result<Self> {
        let (tx, result) = mpsc::channel();
        let cancel = Arc::new(AtomicBool::new(false));
        let (p, flag) = (plan.clone(), cancel.clone());
        std::thread::Builder::new()
            .name("compend-climb".into())
            .spawn(move || {
                // Behind the show: playback keeps its pace on a busy machine.
                let _ = tx.send(crate::background::run(|| climb(p, &flag)));
            })
            .map_err(|e| Error::Failed(format!("cannot start the climb's thread: {e}")))?;
        tracing::info!(
            "progressive calibration: training {} beside playback on {}",
            plan.method,
            plan.setup.display()
        );
        Ok(Self {
            plan,
            started: Instant::now(),
            cancel,
            result,
        })
    }

    /// The outcome once there is one.
    pub(super) fn poll(&self) -> Option<Result<Box<Candidate>>> {
        match self.result.try_recv() {
            Ok(r) => Some(r),
            Err(mpsc::TryRecvError::Empty) => None,
            Err(mpsc::TryRecvError::Disconnected) => Some(Err(Error::Failed(
                "the climb's thread ended without an answer".into(),
            ))),
        }
    }

    /// Seconds since it started.
    pub(super) fn seconds(&self) -> f64 {
        self.started.elapsed().as_secs_f64()
    }
}

impl Drop for Climb {
    /// A climb dropped (a recalibration, a new model, a stop) never installs; its thread ends
    /// with its training.
    fn drop(&mut self) {
        self.cancel.store(true, Ordering::Relaxed);
    }
}

/// Trains the rung and records its figures on the held-out test pairs, for the rig to judge.
fn climb(p: Plan, cancel: &Arc<AtomicBool>) -> Result<Box<Candidate>> {
    let t = Instant::now();
    let setup = Setup::open(&p.setup, Some(&p.root))?;
    let installed = Model::load(&p.model)?;
    // The residual rung's linear part on the installed model's lattice, so the two compare as
    // the same output resolution.
    let residual =
        crate::nn::compennetpp::Variant::from_method(p.method.name()).is_some_and(|v| v.residual());
    let req = fit::Request {
        iters: p.iters,
        device: p.device,
        lattice: residual.then_some(installed.meta.network_size),
        cancel: Some(cancel.clone()),
        ..fit::Request::new(MethodChoice::Rung(p.method))
    };
    let rule = fit::ClimbRule { gain_db: p.gain_db };
    // Trained on every pair (a residual rung's correction on the closed-loop ones), as the
    // rung trains alone. Its paper-protocol figures on the calibration's test pairs go into
    // the record; they do not decide: held-out pairs do not tell what the rig shows
    // (docs/bench/ladder.md, "The rig judges the climb").
    let (mut model, _) = fit::fit(&setup, &req, |_, _, _| {})?;
    let pairs = setup.load_test(None)?;
    let (new, _) = crate::model::paper_protocol(&model, &pairs)?;
    let (old, _) = crate::model::paper_protocol(&installed, &pairs)?;
    let record = ClimbRecord {
        replaced: installed.meta.method.name().to_string(),
        psnr: new.psnr,
        replaced_psnr: old.psnr,
        required_gain_db: p.gain_db,
        seconds: t.elapsed().as_secs_f64(),
        closed_loop: None,
        loop_held_out: None,
    };
    if let Some(w) = rule.caveat("[calibration] climb_gain_db") {
        tracing::warn!("progressive calibration: {w}");
    }
    // The climbed model plays with the calibration it was trained on (its exposure, range and
    // latency).
    let Some(mut calibration) = installed.meta.calibration.clone() else {
        return Err(Error::Failed(format!(
            "{}: the installed model has no calibration record to climb from",
            p.model.display()
        )));
    };
    calibration.climb = Some(record);
    model.meta.calibration = Some(calibration);
    if cancel.load(Ordering::Relaxed) {
        return Err(Error::Cancelled("the climb".into()));
    }
    Ok(Box::new(Candidate {
        plan: p,
        model,
        installed,
        seconds: t.elapsed().as_secs_f64(),
    }))
}

/// The rig's verdict on a candidate, from the closed-loop verifications of the candidate and of
/// the installed model, in that order ([`crate::calibrate::verify_after`]): if it confirms the
/// margin ([`fit::ClimbRule::confirms`]), the candidate, with both closed-loop figures in its
/// `calibration.climb`, is installed at the plan's model path and returned; otherwise nothing
/// changes and the record says why.
pub(super) fn settle(
    _installer: &mut Installer,
    c: Candidate,
    verifications: &[Verification],
) -> Result<std::result::Result<Model, ClimbRecord>> {
    let [upper, lower] = verifications else {
        return Err(Error::Failed(format!(
            "the climb's check on the rig scored {} models, not 2",
            verifications.len()
        )));
    };
    let Candidate {
        plan, mut model, ..
    } = c;
    let rule = fit::ClimbRule {
        gain_db: plan.gain_db,
    };
    let kept = rule.confirms((upper.psnr, upper.passed), (lower.psnr, lower.passed));
    let mut calibration = model
        .meta
        .calibration
        .take()
        .ok_or_else(|| Error::Failed("the climbed model lost its calibration record".into()))?;
    let mut record = calibration
        .climb
        .take()
        .ok_or_else(|| Error::Failed("the climbed model lost its climb record".into()))?;
    record.closed_loop = Some(ClimbClosedLoop {
        psnr: upper.psnr,
        replaced_psnr: lower.psnr,
        passed: upper.passed,
        replaced_passed: lower.passed,
        images: upper.images,
    });
    if !kept {
        return Ok(Err(record));
    }
    calibration.climb = Some(record);
    model.meta.calibration = Some(calibration);
    model.save(&plan.model)?;
    Ok(Ok(model))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fit::TrainDevice;

    #[test]
    fn a_climb_plan_takes_the_configured_rung_and_device() {
        let mut c = crate::config::Config::defaults().calibration;
        let plan = |c: &crate::config::CalibrationConfig, installed| {
            Plan::after_install(
                c,
                installed,
                Path::new("runs/run-1"),
                PathBuf::from("runs/run-1/capture"),
                Path::new("model"),
            )
        };
        // No climb by default.
        assert!(plan(&c, Method::Linear).is_none());
        c.climb = Some(Method::CompenNetPpResFull);
        c.device = TrainDevice::Cuda(1);
        c.climb_iters = Some(300);
        let p = plan(&c, Method::Linear).expect("a climb above the installed linear rung");
        assert_eq!(p.method, Method::CompenNetPpResFull);
        assert_eq!(p.device, TrainDevice::Cuda(1));
        assert_eq!(p.iters, Some(300));
        assert_eq!(p.root, Path::new("runs/run-1"));
        assert_eq!(p.setup, Path::new("runs/run-1/capture"));
        assert_eq!(p.model, Path::new("model"));
        // Nothing to climb to when the calibration installed that rung itself.
        assert!(plan(&c, Method::CompenNetPpResFull).is_none());
    }
}
