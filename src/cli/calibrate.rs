//! `compend calibrate`: from a projector and a camera to a verified, installed model.
//! Today the projector and camera are the virtual rig's (`--rig virtual[:SCENE]`); the V4L2
//! camera and the projector window plug into the same flow (`compend::calibrate`).

use std::path::PathBuf;

use anyhow::{Context, Result};
use compend::calibrate::{self, Options, PatternSet, SyncSettings};
use compend::model::MethodChoice;
use compend::rig::{VirtualRig, scene};

use super::sim::SceneArgs;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// The rig to calibrate: `virtual` (the `curved` scene) or `virtual:SCENE` (a built-in scene
    /// or scene JSON file; see `compend sim list`).
    #[arg(long, value_name = "virtual[:SCENE]")]
    pub rig: String,
    /// Folder for the patterns and captures (a data root; the captures go to DATA/capture). An
    /// interrupted calibration into the same folder resumes from the captures on disk.
    #[arg(long, default_value = "compend-calibration")]
    pub data: PathBuf,
    /// Model directory to install the verified model into [default: DATA/model]. Only a model
    /// directory there is replaced, and only by a model that verified.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// The rung to fit.
    #[arg(long, value_enum, default_value = "linear")]
    pub method: MethodChoice,
    /// Sampling images to project for training.
    #[arg(long, default_value_t = 48)]
    pub ntrain: usize,
    /// Test images to project: captured for `eval`, and the first few for the verification.
    #[arg(long, default_value_t = 10)]
    pub ntest: usize,
    /// Test images projected compensated and uncompensated in the verification.
    #[arg(long, default_value_t = 5)]
    pub verify: usize,
    /// PSNR gain over the uncompensated projection a model needs to be installed, dB.
    #[arg(long, default_value_t = 1.0)]
    pub min_gain: f64,
    /// Frames averaged per capture.
    #[arg(long, default_value_t = 3)]
    pub average: usize,
    /// Virtual rig only: projector-to-camera delay, milliseconds (default: the scene's).
    #[arg(long, value_name = "MS")]
    pub rig_latency_ms: Option<f64>,
    /// Virtual rig only: camera frame rate, Hz (default: the scene's).
    #[arg(long, value_name = "HZ")]
    pub rig_fps: Option<f64>,
    /// Network size of the sampling images, and the virtual rig's camera and projector sizes.
    #[command(flatten)]
    pub scene_args: SceneArgs,
    /// Print the calibration record as one JSON object on stdout.
    #[arg(long)]
    pub json: bool,
}

pub fn run(args: Args) -> Result<()> {
    let out = args.out.clone().unwrap_or_else(|| args.data.join("model"));
    // Before any work: where the model goes must take a model, and the numbers must make sense.
    compend::model::store::check_output(&out)?;
    check_counts(&args)?;
    let scene_name = match args.rig.split_once(':') {
        None if args.rig == "virtual" => "curved".to_string(),
        Some(("virtual", s)) if !s.is_empty() => s.to_string(),
        _ => {
            return Err(compend::Error::Input(format!(
                "--rig {:?}: expected `virtual` or `virtual:SCENE` (scenes: {}); real cameras \
                 and projectors are not supported by calibrate yet",
                args.rig,
                scene::BUILTIN.join(", ")
            ))
            .into());
        }
    };
    let mut scene = super::sim::resolve(&scene_name, &args.scene_args)?;
    if let Some(fps) = args.rig_fps {
        scene.latency.fps = fps;
    }
    if let Some(ms) = args.rig_latency_ms {
        scene.latency.delay_frames = (ms / 1e3 * scene.latency.fps).round() as u32;
    }
    scene.validate()?;
    let rig = VirtualRig::new(&scene, args.scene_args.seed)
        .with_context(|| format!("preparing the virtual rig (scene {scene_name:?})"))?;
    let (mut display, mut camera) = (rig.clone(), rig);
    let opts = Options {
        patterns: PatternSet {
            seed: args.scene_args.seed,
            ntrain: args.ntrain,
            ntest: args.ntest,
            network: args.scene_args.network,
            projector: scene.projector.size(),
            gray_level: compend::patterns::DEFAULT_GRAY_LEVEL,
        },
        method: args.method,
        fit_seed: 0,
        sync: SyncSettings {
            average: args.average,
            ..SyncSettings::default()
        },
        verify_images: args.verify,
        required_gain_db: args.min_gain,
        rig: format!("virtual:{scene_name}"),
    };
    eprintln!(
        "calibrate: virtual rig {scene_name:?} (camera {}, projector {}, {} fps, {} frames of \
         delay, {:.0} % drops) into {}",
        scene.camera.size(),
        scene.projector.size(),
        scene.latency.fps,
        scene.latency.delay_frames,
        scene.latency.drop_rate * 100.0,
        args.data.display()
    );
    let bar = super::progress_bar(args.json);
    let mut progress = |stage: &str, done: usize, total: usize| {
        bar.set_length(total as u64);
        bar.set_position(done as u64);
        bar.set_message(stage.to_string());
    };
    let done = calibrate::calibrate(&mut display, &mut camera, &args.data, &opts, &mut progress)
        .with_context(|| format!("calibrating into {}", args.data.display()))?;
    bar.finish_and_clear();
    let r = &done.record;
    let v = &r.verification;
    let s = &r.seconds;
    eprintln!(
        "calibrate: latency {:?} exposures (skipping {} per capture); {} captures taken, {} \
         found on disk, {} retaken",
        r.latency.trials, r.latency.settle_frames, r.captured, r.resumed, r.retakes
    );
    eprintln!(
        "calibrate: seconds: latency {:.1}, patterns {:.1}, captures {:.1}, training {:.1}, \
         verification {:.1}, total {:.1}",
        s.latency, s.patterns, s.captures, s.training, s.verification, s.total
    );
    eprintln!(
        "calibrate: verification on {} test images in the displayable area: {:.2} dB / SSIM \
         {:.3} compensated, {:.2} dB / SSIM {:.3} uncompensated: {:+.2} dB (needs {:+.2})",
        v.images,
        v.psnr,
        v.ssim,
        v.uncompensated_psnr,
        v.uncompensated_ssim,
        v.gain_db,
        v.required_gain_db
    );
    if args.json {
        println!("{}", serde_json::to_string(r)?);
    }
    if !v.passed {
        return Err(compend::Error::Failed(format!(
            "the {} model did not verify ({:+.2} dB over the uncompensated projection, {:+.2} \
             needed); it was not installed and {} is unchanged",
            done.model.meta.method,
            v.gain_db,
            v.required_gain_db,
            out.display()
        ))
        .into());
    }
    let mut model = done.model;
    model.meta.calibration = Some(done.record);
    model
        .save(&out)
        .with_context(|| format!("installing the model into {}", out.display()))?;
    eprintln!(
        "calibrate: installed {} into {}",
        model.meta.method,
        out.display()
    );
    Ok(())
}

/// The counts must allow a fit and a verification.
fn check_counts(a: &Args) -> compend::Result<()> {
    let bad = |what: String| Err(compend::Error::Input(what));
    if a.ntrain < compend::fit::MIN_TRAIN {
        return bad(format!(
            "--ntrain {}: at least {} training images are needed",
            a.ntrain,
            compend::fit::MIN_TRAIN
        ));
    }
    if a.ntest == 0 || a.verify == 0 || a.verify > a.ntest {
        return bad(format!(
            "--ntest {} / --verify {}: the verification projects 1 to NTEST test images",
            a.ntest, a.verify
        ));
    }
    if a.average == 0 {
        return bad("--average 0: at least one frame per capture".into());
    }
    if !(a.min_gain.is_finite()) {
        return bad(format!(
            "--min-gain {}: expected a number of dB",
            a.min_gain
        ));
    }
    for (flag, v) in [
        ("--rig-latency-ms", a.rig_latency_ms),
        ("--rig-fps", a.rig_fps),
    ] {
        if let Some(v) = v
            && !(v.is_finite() && v >= 0.0)
        {
            return bad(format!("{flag} {v}: expected a non-negative number"));
        }
    }
    Ok(())
}
