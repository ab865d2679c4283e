//! Progressive calibration: once a calibration has installed its model and playback has
//! started, the next rung (`[calibration] climb`) trains on a thread of its own on the same
//! captures. It is judged on the calibration's held-out test pairs (captured, never trained on;
//! the paper protocol) against the installed model; only if it beats it by `climb_gain_db`
//! ([`fit::ClimbRule`], the rule of `--method auto`) is it installed (the atomic model-directory swap) and its pass built, for the playback loop to
//! swap in at its next frame. The viewer sees the cheap rung within a minute, and the better one
//! when, and only if, it is better.

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, mpsc};
use std::time::Instant;

use crate::dataset::Setup;
use crate::error::{Error, Result};
use crate::fit;
use crate::gpu::{CompensationPass, GpuContext};
use crate::model::store::ClimbRecord;
use crate::model::{Method, MethodChoice, Model};
use crate::raster::ImageSize;

/// Held while a model directory is replaced, by the engine's install and by a climb's: a climb
/// that was cancelled (a recalibration began) never installs after the check.
pub(super) static INSTALL: Mutex<()> = Mutex::new(());

/// What to climb to, after which calibration.
#[derive(Clone, Debug)]
pub(super) struct Plan {
    pub(super) method: Method,
    pub(super) iters: Option<usize>,
    pub(super) gain_db: f64,
    /// The calibration's data root and its setup.
    pub(super) root: PathBuf,
    pub(super) setup: PathBuf,
    /// The installed model directory: what the climb must beat, and where it installs.
    pub(super) model: PathBuf,
}

/// How a climb ended.
pub(super) enum Outcome {
    /// Better by the margin: installed at the plan's model path; its pass is ready.
    Installed(Box<(Model, CompensationPass)>),
    /// Not better: nothing changed.
    Kept(ClimbRecord),
}

/// A climb under way.
pub(super) struct Climb {
    pub(super) plan: Plan,
    started: Instant,
    cancel: Arc<AtomicBool>,
    result: mpsc::Receiver<Result<Outcome>>,
}

impl Climb {
    /// Starts training `plan.method`; a pass for a display of `display` projector pixels is
    /// built on (a clone of) `ctx` if it installs.
    pub(super) fn start(plan: Plan, ctx: GpuContext, display: ImageSize) -> Result<Self> {
        let (tx, result) = mpsc::channel();
        let cancel = Arc::new(AtomicBool::new(false));
        let (p, flag) = (plan.clone(), cancel.clone());
        std::thread::Builder::new()
            .name("compend-climb".into())
            .spawn(move || {
                let _ = tx.send(climb(&p, &flag, &ctx, display));
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
    pub(super) fn poll(&self) -> Option<Result<Outcome>> {
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

/// Trains, judges and, if better, installs.
fn climb(
    p: &Plan,
    cancel: &Arc<AtomicBool>,
    ctx: &GpuContext,
    display: ImageSize,
) -> Result<Outcome> {
    let t = Instant::now();
    let setup = Setup::open(&p.setup, Some(&p.root))?;
    let installed = Model::load(&p.model)?;
    // The residual rung's linear part on the installed model's lattice, so the two compare as
    // the same output resolution.
    let residual =
        crate::nn::compennetpp::Variant::from_method(p.method.name()).is_some_and(|v| v.residual());
    let req = fit::Request {
        method: MethodChoice::Rung(p.method),
        ntrain: None,
        seed: 0,
        iters: p.iters,
        batch: None,
        device: Default::default(),
        lattice: residual.then_some(installed.meta.network_size),
        projector: None,
        photometric: Default::default(),
        cancel: Some(cancel.clone()),
        climb_gain_db: None,
    };
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
    };
    let rule = fit::ClimbRule { gain_db: p.gain_db };
    if !rule.climbs(new.psnr, old.psnr) {
        return Ok(Outcome::Kept(record));
    }
    // The climbed model plays with the calibration it was trained on (its exposure and range).
    let Some(mut calibration) = installed.meta.calibration.clone() else {
        return Err(Error::Failed(format!(
            "{}: the installed model has no calibration record to climb from",
            p.model.display()
        )));
    };
    calibration.climb = Some(record);
    model.meta.calibration = Some(calibration);
    let pass = CompensationPass::for_display(ctx, &model, display, model.display_range())?;
    let _guard = INSTALL.lock().unwrap_or_else(|e| e.into_inner());
    if cancel.load(Ordering::Relaxed) {
        return Err(Error::Cancelled("the climb".into()));
    }
    model.save(&p.model)?;
    Ok(Outcome::Installed(Box::new((model, pass))))
}
