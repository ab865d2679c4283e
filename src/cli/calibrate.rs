//! `compend calibrate`: from a projector and a camera to a verified, installed model, through
//! the flow of `compend::calibrate`.
//!
//! Rigs: `--rig virtual[:SCENE]`, the virtual rig's projector and camera; `--rig window[:SCENE]`,
//! the real projector window (on `--monitor`) watched by a virtual camera that sees what the
//! window presented (read back from the GPU) through the scene's surface, camera and latency
//! (`compend::rig::window_camera`). The V4L2 camera plugs into the same flow.

use std::path::{Path, PathBuf};
use std::time::Duration;

use anyhow::{Context, Result};
use compend::calibrate::{self, Calibrated, Options, PatternSet, SyncSettings};
use compend::device::{DisplaySink, FrameSource};
use compend::model::MethodChoice;
use compend::rig::VirtualRig;
use compend::rig::scene::{self, Scene};
use compend::rig::window_camera::{Shown, WindowCamera};
use compend::window::ProjectorWindow;

use super::sim::SceneArgs;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// The rig to calibrate: `virtual[:SCENE]`, the virtual rig; `window[:SCENE]`, the projector
    /// window watched by a virtual camera that sees what the window presented through the
    /// scene's surface and camera. SCENE: a built-in scene or scene JSON file (see `compend sim
    /// list`) [default: curved].
    #[arg(
        long,
        value_name = "virtual|window[:SCENE]",
        required_unless_present = "camera"
    )]
    pub rig: Option<String>,
    /// Calibrate real hardware: this V4L2 camera (e.g. /dev/video0 or a /dev/v4l/by-id/ path)
    /// looking at the projector window on `--monitor`. Its exposure, gain, white balance, focus,
    /// backlight compensation and power-line filter are locked first, and the values it
    /// accepted are printed.
    #[arg(long, value_name = "DEV", conflicts_with = "rig")]
    pub camera: Option<PathBuf>,
    /// `--camera` only: the capture size WxH [default: the camera's current size].
    #[arg(long, value_name = "WxH", value_parser = super::sim::parse_size, requires = "camera")]
    pub camera_size: Option<compend::raster::ImageSize>,
    /// `--rig window` only: the projector's monitor, its name or index [default: the primary
    /// monitor]. The projector size is the monitor's.
    #[arg(long)]
    pub monitor: Option<String>,
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
    /// Virtual camera only: projector-to-camera delay, milliseconds (default: the scene's).
    #[arg(long, value_name = "MS")]
    pub rig_latency_ms: Option<f64>,
    /// Virtual camera only: camera frame rate, Hz (default: the scene's).
    #[arg(long, value_name = "HZ")]
    pub rig_fps: Option<f64>,
    /// Seed of the sampling images (and of the virtual rig's texture and noise).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Network size of the sampling images: N (square) or WxH, sides divisible by 4.
    #[arg(long, default_value = "256", value_name = "N|WxH", value_parser = super::sim::parse_network)]
    pub network: compend::raster::ImageSize,
    /// Virtual camera only: its resolution WxH (default: the scene's, 640x480 for built-in
    /// scenes).
    #[arg(long, value_name = "WxH", value_parser = super::sim::parse_size)]
    pub rig_camera: Option<compend::raster::ImageSize>,
    /// Virtual rig only: the projector resolution WxH (default: the scene's, 800x600); the
    /// window's is its monitor's.
    #[arg(long, value_name = "WxH", value_parser = super::sim::parse_size)]
    pub projector: Option<compend::raster::ImageSize>,
    /// Print the calibration record as one JSON object on stdout.
    #[arg(long)]
    pub json: bool,
}

/// Which display the patterns go to.
#[derive(Clone, Copy, Debug, PartialEq)]
enum RigKind {
    /// The virtual rig's projector.
    Virtual,
    /// The projector window.
    Window,
}

/// `virtual[:SCENE]` or `window[:SCENE]`: the kind and the scene name.
fn parse_rig(rig: &str) -> compend::Result<(RigKind, String)> {
    let (kind, scene) = match rig.split_once(':') {
        None => (rig, "curved"),
        Some((k, s)) if !s.is_empty() => (k, s),
        Some((k, _)) => (k, ""),
    };
    match (kind, scene.is_empty()) {
        ("virtual", false) => Ok((RigKind::Virtual, scene.to_string())),
        ("window", false) => Ok((RigKind::Window, scene.to_string())),
        _ => Err(compend::Error::Input(format!(
            "--rig {rig:?}: expected `virtual`, `virtual:SCENE`, `window` or `window:SCENE` \
             (scenes: {}); real cameras are not supported by calibrate yet",
            scene::BUILTIN.join(", ")
        ))),
    }
}

pub fn run(args: Args) -> Result<()> {
    let out = args.out.clone().unwrap_or_else(|| args.data.join("model"));
    // Before any work: where the model goes must take a model, and the numbers must make sense.
    compend::model::store::check_output(&out)?;
    check_counts(&args)?;
    let Some(rig) = &args.rig else {
        let device = args.camera.clone().unwrap_or_default();
        return run_hardware(&args, &out, &device);
    };
    let (kind, scene_name) = parse_rig(rig)?;
    match kind {
        RigKind::Virtual => {
            if args.monitor.is_some() {
                return Err(compend::Error::Input(
                    "--monitor: only `--rig window` shows the patterns on a monitor".into(),
                )
                .into());
            }
            run_virtual(&args, &out, &scene_name)
        }
        RigKind::Window => run_window(&args, &out, &scene_name),
    }
}

/// The scene with the camera timing of `--rig-fps` and `--rig-latency-ms`, and the projector
/// size `projector` when given (the window's).
fn scene_for(
    args: &Args,
    name: &str,
    projector: Option<compend::raster::ImageSize>,
) -> Result<Scene> {
    let scene_args = SceneArgs {
        seed: args.seed,
        camera: args.rig_camera,
        projector: args.projector,
        network: args.network,
    };
    let mut scene = super::sim::resolve(name, &scene_args)?;
    if let Some(p) = projector {
        let camera = scene.camera.size();
        scene = scene.with_resolution(camera, p);
    }
    if let Some(fps) = args.rig_fps {
        scene.latency.fps = fps;
    }
    if let Some(ms) = args.rig_latency_ms {
        scene.latency.delay_frames = (ms / 1e3 * scene.latency.fps).round() as u32;
    }
    scene.validate()?;
    Ok(scene)
}

/// The camera's timing for the log: fps, delay and drops.
fn describe_camera(scene: &Scene) -> String {
    let l = &scene.latency;
    format!(
        "camera {}, {} fps, {} frames ({:.0} ms) of delay, {:.0} % drops",
        scene.camera.size(),
        l.fps,
        l.delay_frames,
        l.delay_frames as f64 / l.fps * 1e3,
        l.drop_rate * 100.0
    )
}

/// Calibrates real hardware: a V4L2 camera looking at the projector window.
#[cfg(target_os = "linux")]
fn run_hardware(args: &Args, out: &Path, device: &Path) -> Result<()> {
    // The camera first: a missing or wrong device fails before a window opens.
    let mut camera = compend::camera::V4l2Camera::open(device, args.camera_size)?;
    let report = camera
        .lock_for_calibration(&compend::camera::LockSettings::default())
        .with_context(|| format!("locking the controls of {}", device.display()))?;
    for line in report.lines() {
        eprintln!("calibrate: {}: {line}", device.display());
    }
    let mut win = ProjectorWindow::open(args.monitor.as_deref())?;
    let size = DisplaySink::size(&win);
    eprintln!(
        "calibrate: projector window {size} at {} Hz on {} ({}), camera {} ({}) into {}",
        win.refresh_hz(),
        args.monitor.as_deref().unwrap_or("the primary monitor"),
        win.context().describe(),
        device.display(),
        FrameSource::size(&camera),
        args.data.display()
    );
    let done = calibrate_on(
        &mut win,
        &mut camera,
        args,
        size,
        format!("camera:{}", device.display()),
    );
    install(done?, out)
}

#[cfg(not(target_os = "linux"))]
fn run_hardware(_: &Args, _: &Path, device: &Path) -> Result<()> {
    Err(compend::Error::Input(format!(
        "--camera {}: V4L2 cameras exist on Linux only",
        device.display()
    ))
    .into())
}

/// Calibrates on the virtual rig.
fn run_virtual(args: &Args, out: &Path, scene_name: &str) -> Result<()> {
    let scene = scene_for(args, scene_name, None)?;
    let rig = VirtualRig::new(&scene, args.seed)
        .with_context(|| format!("preparing the virtual rig (scene {scene_name:?})"))?;
    let (mut display, mut camera) = (rig.clone(), rig);
    eprintln!(
        "calibrate: virtual rig {scene_name:?} (projector {}, {}) into {}",
        scene.projector.size(),
        describe_camera(&scene),
        args.data.display()
    );
    let rig = format!("virtual:{scene_name}");
    let done = calibrate_on(&mut display, &mut camera, args, scene.projector.size(), rig)?;
    install(done, out)
}

/// Calibrates through the projector window, watched by a virtual camera.
fn run_window(args: &Args, out: &Path, scene_name: &str) -> Result<()> {
    let mut win = ProjectorWindow::open(args.monitor.as_deref())?;
    let size = DisplaySink::size(&win);
    if let Some(p) = args.projector
        && p != size
    {
        return Err(compend::Error::Input(format!(
            "--projector {p}: the projector window on {} is {size}; leave --projector out or \
             pick the monitor of that size",
            args.monitor.as_deref().unwrap_or("the primary monitor")
        ))
        .into());
    }
    let scene = scene_for(args, scene_name, Some(size))?;
    // The camera looks back the delay; a quarter second more covers a camera rendering late
    // (one that falls further behind skips the exposures it missed).
    let l = &scene.latency;
    let keep = Duration::from_secs_f64(0.25 + (l.delay_frames as f64 + 4.0) / l.fps);
    let log = win.record_presented(keep);
    let look = move |t| {
        log.at(t).map(|p| Shown {
            index: p.index,
            at: p.at,
            image: p.image,
        })
    };
    let mut camera = WindowCamera::start(&scene, args.seed, look)
        .with_context(|| format!("preparing the virtual camera (scene {scene_name:?})"))?;
    eprintln!(
        "calibrate: projector window {size} at {} Hz on {} ({}), virtual camera on scene \
         {scene_name:?} ({}) into {}",
        win.refresh_hz(),
        args.monitor.as_deref().unwrap_or("the primary monitor"),
        win.context().describe(),
        describe_camera(&scene),
        args.data.display()
    );
    let rig = format!("window:{scene_name}");
    let done = calibrate_on(&mut win, &mut camera, args, scene.projector.size(), rig);
    report_window_timing(&win, &camera, &scene);
    if let Ok(d) = &done {
        let trials = &d.record.latency.trials;
        let worst = trials.iter().copied().max().unwrap_or(0);
        eprintln!(
            "calibrate: measured latency {worst} exposures = {:.0} ms at {} fps (scene delay \
             {:.0} ms)",
            worst as f64 / l.fps * 1e3,
            l.fps,
            l.delay_frames as f64 / l.fps * 1e3
        );
    }
    drop(camera);
    install(done?, out)
}

/// Prints how presenting and the camera went, as `key=value` pairs.
fn report_window_timing(win: &ProjectorWindow, camera: &WindowCamera, scene: &Scene) {
    let w = win.show_timing();
    eprintln!(
        "calibrate: window: shows={} skipped={} refresh_hz={} present_interval_ms={:.1}..{:.1} \
         waited_s={:.2} readback_ms={:.2}/{:.2} recorded={}",
        w.shows,
        w.skipped,
        win.refresh_hz(),
        w.interval_ms_min,
        w.interval_ms_max,
        w.waited_s,
        w.readback_ms_mean,
        w.readback_ms_max,
        w.recorded
    );
    let c = camera.timing();
    eprintln!(
        "calibrate: camera: fps={} exposures={} delivered={} dropped={} overflowed={} behind={} \
         changes={} lag_ms={:.1}..{:.1} render_ms={:.2}",
        scene.latency.fps,
        c.exposures,
        c.delivered,
        c.dropped,
        c.overflowed,
        c.behind,
        c.changes,
        c.lag_ms_min,
        c.lag_ms_max,
        c.render_ms_mean
    );
}

/// Runs the calibration flow on a display and a camera and prints its record.
fn calibrate_on<D: DisplaySink + ?Sized, C: FrameSource + ?Sized>(
    display: &mut D,
    camera: &mut C,
    args: &Args,
    projector: compend::raster::ImageSize,
    rig: String,
) -> Result<Calibrated> {
    let opts = Options {
        patterns: PatternSet {
            seed: args.seed,
            ntrain: args.ntrain,
            ntest: args.ntest,
            network: args.network,
            projector,
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
        rig,
    };
    let bar = super::progress_bar(args.json);
    let mut progress = |stage: &str, done: usize, total: usize| {
        bar.set_length(total as u64);
        bar.set_position(done as u64);
        bar.set_message(stage.to_string());
    };
    let done = calibrate::calibrate(display, camera, &args.data, &opts, &mut progress)
        .with_context(|| format!("calibrating into {}", args.data.display()))?;
    bar.finish_and_clear();
    print_record(&done, args.json)?;
    Ok(done)
}

/// The phase times and verification figures on stderr; the record on stdout with `--json`.
fn print_record(done: &Calibrated, json: bool) -> Result<()> {
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
    if json {
        println!("{}", serde_json::to_string(r)?);
    }
    Ok(())
}

/// Installs the model into `out` if it verified; otherwise says why not, `out` unchanged.
fn install(done: Calibrated, out: &Path) -> Result<()> {
    let v = &done.record.verification;
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
        .save(out)
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
