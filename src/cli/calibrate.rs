//! `compend calibrate`: from a projector and a camera to a verified, installed model, through
//! the flow of `compend::calibrate`.
//!
//! Rigs: `--rig virtual[:SCENE]`, the virtual rig's projector and camera; `--rig window[:SCENE]`,
//! the real projector window (on `--monitor`) watched by a virtual camera that sees what the
//! window presented (read back from the GPU) through the scene's surface, camera and latency
//! (`compend::rig::window_camera`). The V4L2 camera plugs into the same flow.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::{Context, Result};
use compend::calibrate::runs::Runs;
use compend::calibrate::{self, Calibrated};
use compend::config::{CalibrationConfig, Config, RigConfig, RigKind};
use compend::device::{DisplaySink, FrameSource};
use compend::model::MethodChoice;
use compend::raster::ImageSize;
use compend::rig::scene::{self, Scene};
use compend::rig::window_camera::WindowCamera;
use compend::rigs::{self, Given, Opened, RigClock};
use compend::window::ProjectorWindow;

#[derive(clap::Args, Debug)]
#[command(group(
    clap::ArgGroup::new("what")
        .required(true)
        .multiple(true)
        .args(["rig", "camera", "config"])
))]
pub struct Args {
    /// Take the rig, the paths and the calibration settings from this configuration file (the
    /// service's; config/compend.toml documents every key). Flags given here win over the file.
    /// Without `--rig` or `--camera` the file's `[rig]` is calibrated, the captures go to its
    /// `[paths] data` and the model is installed into its `[paths] model`, which is what
    /// `compend serve` plays (stop the service first: the devices are not shared).
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
    /// The rig to calibrate: `virtual[:SCENE]`, the virtual rig; `window[:SCENE]`, the projector
    /// window watched by a virtual camera that sees what the window presented through the
    /// scene's surface and camera. SCENE: a built-in scene or scene JSON file (see `compend sim
    /// list`) [default: curved].
    #[arg(long, value_name = "virtual|window[:SCENE]")]
    pub rig: Option<String>,
    /// Calibrate real hardware: this V4L2 camera (a path such as /dev/video0 or a
    /// /dev/v4l/by-id/ link, or a camera's index or part of its name) looking at the projector window on `--monitor`. Its exposure, gain, white balance, focus,
    /// backlight compensation and power-line filter are locked first, and the values it
    /// accepted are printed.
    #[arg(long, value_name = "DEV", conflicts_with = "rig")]
    pub camera: Option<PathBuf>,
    /// `--camera` only: the capture size WxH [default: the camera's current size].
    #[arg(long, value_name = "WxH", value_parser = super::sim::parse_size)]
    pub camera_size: Option<ImageSize>,
    /// `--rig window` and `--camera`: the projector's monitor, its name or index [default: the
    /// primary monitor]. The projector size is the monitor's. A set of projectors names one
    /// monitor per projector, in order: `--monitor HDMI-1,HDMI-2` (with `--camera`, several
    /// monitors make a set).
    #[arg(long)]
    pub monitor: Option<String>,
    /// Folder for the patterns and captures (a data root; the captures go to DATA/capture). An
    /// interrupted calibration into the same folder resumes from the captures on disk
    /// [default: compend-calibration, or the configuration's `[paths] data`].
    #[arg(long)]
    pub data: Option<PathBuf>,
    /// Model directory to install the verified model into [default: DATA/model, or the
    /// configuration's `[paths] model`]. Only a model directory there is replaced, and only by a
    /// model that verified.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// The rung to fit [default: linear].
    #[arg(long, value_enum)]
    pub method: Option<MethodChoice>,
    /// Sampling images to project for training, or `auto`: in rounds (16, then 8 more at a
    /// time, up to 48), the linear rung fitted after each and scored on the held-out test
    /// pairs, until a round no longer gains; then 8 closed-loop pairs, and as many more as the
    /// sampling pairs where the model's own error on those is at least 15 % of their
    /// closed-loop error. model.json records both choices and why [default: the
    /// configuration's `ntrain`, 48].
    #[arg(long, value_name = "N|auto")]
    pub ntrain: Option<compend::calibrate::SamplingCount>,
    /// Test images to project: captured for `eval`, and the first few for the verification
    /// [default: 10].
    #[arg(long)]
    pub ntest: Option<usize>,
    /// Test images projected compensated and uncompensated in the verification [default: 5].
    #[arg(long)]
    pub verify: Option<usize>,
    /// PSNR gain over the uncompensated projection a model needs to be installed, dB
    /// [default: 1].
    #[arg(long)]
    pub min_gain: Option<f64>,
    /// `--method auto` only: the PSNR gain in dB the CompenNet++ rung, trained on every pair,
    /// needs over the best linear rung in closed loop on the rig (the verification images) to
    /// be installed [default: the configuration's `climb_gain_db`, 0.2].
    #[arg(long, value_name = "DB", allow_hyphen_values = true)]
    pub climb_gain: Option<f64>,
    /// `--method auto` only: training iterations of the CompenNet++ rung it climbs to
    /// [default: the configuration's `climb_iters`, else the rung's own schedule].
    #[arg(long)]
    pub climb_iters: Option<usize>,
    /// CompenNet++ rungs only: training iterations [default: the rung's own schedule].
    #[arg(long)]
    pub iters: Option<usize>,
    /// Where a CompenNet++ rung trains, `cpu`, `cuda` or `cuda:N` (an NVIDIA GPU; needs a build
    /// with `--features cuda`); with `--method auto` it also chooses the rung climbed to
    /// (compennet++-res on the CPU, compennet++-res-full on a GPU). The linear rungs fit on the
    /// CPU [default: the configuration's `device`, cpu].
    #[arg(long)]
    pub device: Option<compend::fit::TrainDevice>,
    /// linear, linear-sl, the residual rungs and auto only: after the linear fit, project its
    /// compensation of N sampling images placed as desired views and capture them
    /// (closed-loop pairs: they sit in the range the desired images use); a linear rung (and
    /// the one auto keeps) is refitted on every pair, a residual rung trains its correction on
    /// them, and auto with 8 or more trains its climb's correction on them; 0: none [default: the
    /// configuration's `loop_images`, else as many as --ntrain].
    #[arg(long, value_name = "N")]
    pub loop_images: Option<usize>,
    /// auto only: the display refresh rate the climb's live pass is weighed at. The rung auto
    /// would climb to is timed first on the GPU that is to play the model, at the projector's
    /// resolution, and is not trained when its pass takes more than half of one refresh
    /// period, or cannot be timed; 0: not weighed. Default: the configuration's `refresh_hz`,
    /// else the projector window's rate (window and camera rigs). The virtual rig's projector
    /// plays through no GPU, so there it is weighed only when a rate is given, on this
    /// machine's GPU.
    #[arg(long, value_name = "HZ", allow_hyphen_values = true)]
    pub refresh_hz: Option<f64>,
    /// Frames averaged per capture [default: 3].
    #[arg(long)]
    pub average: Option<usize>,
    /// Virtual camera only: projector-to-camera delay, milliseconds (default: the scene's).
    #[arg(long, value_name = "MS")]
    pub rig_latency_ms: Option<f64>,
    /// Virtual camera only: camera frame rate, Hz (default: the scene's).
    #[arg(long, value_name = "HZ")]
    pub rig_fps: Option<f64>,
    /// `--rig virtual` only: `wall` delivers the camera's frames no faster than its frame rate,
    /// as a real camera does, so the phase times are those of a rig; `simulated` as fast as
    /// they are computed (for tests and benches of the fit).
    #[arg(long, value_enum, default_value_t = RigClock::Wall)]
    pub rig_clock: RigClock,
    /// Seed of the sampling images (and of the virtual rig's texture and noise) [default: 0].
    #[arg(long)]
    pub seed: Option<u64>,
    /// Network size of the sampling images: N (square) or WxH, sides divisible by 4
    /// [default: 256].
    #[arg(long, value_name = "N|WxH", value_parser = super::sim::parse_network)]
    pub network: Option<ImageSize>,
    /// Virtual camera only: its resolution WxH (default: the scene's, 640x480 for built-in
    /// scenes).
    #[arg(long, value_name = "WxH", value_parser = super::sim::parse_size)]
    pub rig_camera: Option<ImageSize>,
    /// Virtual rig only: the projector resolution WxH (default: the scene's, 800x600); the
    /// window's is its monitor's.
    #[arg(long, value_name = "WxH", value_parser = super::sim::parse_size)]
    pub projector: Option<ImageSize>,
    /// Print the calibration record as one JSON object on stdout.
    #[arg(long)]
    pub json: bool,
}

/// What one calibration runs with: the flags, then the configuration file, then the defaults
/// (the configuration's, so `calibrate` and `serve` agree).
#[derive(Debug)]
struct Settings {
    rig_clock: RigClock,
    rig: Option<String>,
    camera: Option<PathBuf>,
    camera_size: Option<ImageSize>,
    monitor: Option<String>,
    data: PathBuf,
    out: PathBuf,
    /// What is calibrated and how: the configuration's `[calibration]` (or its defaults) with
    /// the flags written over it, as the service would take it
    /// ([`compend::rigs::calibration_options`]).
    calibration: CalibrationConfig,
    /// The `[rig]` the flags are written over: the configuration's, or the defaults.
    base_rig: RigConfig,
    /// The rig is the configuration's `[rig]` (no --rig or --camera): errors name its keys.
    rig_from_file: bool,
    /// Iterations of the CompenNet++ rung: `--iters` for one asked for, `--climb-iters` (the
    /// config's `climb_iters`) for the one `auto` climbs to.
    iters: Option<usize>,
    rig_latency_ms: Option<f64>,
    rig_fps: Option<f64>,
    seed: u64,
    rig_camera: Option<ImageSize>,
    projector: Option<ImageSize>,
    json: bool,
    /// With `--config` and no `--data`: the runs folder (`[paths] data`) and how many runs to
    /// keep; the calibration goes to a run folder of its own, as the service's do.
    runs: Option<(Runs, usize)>,
    /// With `--config`: the service's state directory (`[paths] state`), locked while this
    /// calibration runs ([`compend::service::lock_state`]).
    state: Option<PathBuf>,
}

impl Settings {
    fn new(a: Args) -> Result<Self> {
        let file = a.config.as_deref().map(Config::load).transpose()?;
        let c = file.clone().unwrap_or_else(Config::defaults);
        // The file's [rig] is the rig when the command line names none.
        let rig_from_file = file.is_some() && a.rig.is_none() && a.camera.is_none();
        let r = &c.rig;
        let (rig, camera) = match (rig_from_file, r.kind) {
            (false, _) => (a.rig, a.camera),
            (true, RigKind::Virtual) => (Some(format!("virtual:{}", r.scene)), None),
            (true, RigKind::Window) => (Some(format!("window:{}", r.scene)), None),
            (true, RigKind::Camera) => (None, r.camera.clone()),
        };
        let from = |kinds: &[RigKind]| rig_from_file && kinds.contains(&r.kind);
        let method = a.method.unwrap_or(c.calibration.method);
        if method != MethodChoice::Auto {
            let flag = match (a.climb_gain, a.climb_iters) {
                (Some(g), _) => Some(format!("--climb-gain {g}")),
                (None, Some(n)) => Some(format!("--climb-iters {n}")),
                (None, None) => None,
            };
            if let Some(flag) = flag {
                return Err(compend::Error::Input(format!(
                    "{flag}: only `--method auto` climbs the ladder; {method} is one rung"
                ))
                .into());
            }
        }
        // The flag alone: the configuration's refresh_hz is checked with the file.
        super::refresh_rate(
            a.refresh_hz,
            method == MethodChoice::Auto,
            &format!("{method} is one rung"),
        )?;
        if let Some(n) = a.iters {
            let closed_form = match method {
                MethodChoice::Auto => Some("use --climb-iters for the rung `auto` climbs to"),
                MethodChoice::Rung(m) if m.is_linear() => Some("it is a closed-form fit"),
                MethodChoice::Rung(_) => None,
            };
            if let Some(why) = closed_form {
                return Err(compend::Error::Input(format!(
                    "--iters {n}: only the CompenNet++ rungs train in iterations, not {method} \
                     ({why})"
                ))
                .into());
            }
        }
        let asked = a.loop_images.or(c.calibration.loop_images);
        let ntrain = a.ntrain.unwrap_or(c.calibration.ntrain);
        if ntrain == compend::calibrate::SamplingCount::Auto
            && let Some(p) = compend::calibrate::rounds_problem(method)
        {
            let from = match a.ntrain {
                Some(_) => "--ntrain auto".to_string(),
                None => "the configuration's ntrain = \"auto\"".to_string(),
            };
            return Err(compend::Error::Input(format!("{from}: {p}")).into());
        }
        let loop_images = compend::calibrate::loop_images(method, ntrain.most(), asked);
        if let Some(p) = compend::calibrate::loop_images_problem(method, loop_images) {
            let from = match a.loop_images {
                Some(n) => format!("--loop-images {n}"),
                None => format!("the configuration's loop_images = {loop_images}"),
            };
            return Err(compend::Error::Input(format!("{from}: {p}")).into());
        }
        if method == MethodChoice::Auto {
            let (gain, name) = match a.climb_gain {
                Some(g) => (g, "--climb-gain"),
                None => (c.calibration.climb_gain_db, "climb_gain_db"),
            };
            if let Some(w) = (compend::fit::ClimbRule { gain_db: gain }).caveat(name) {
                eprintln!("warning: {w}");
            }
        }
        // A device this build or machine cannot train on fails before anything is projected,
        // when the method trains on it.
        let device = a.device.unwrap_or(c.calibration.device);
        if method.may_train_a_network() && device != compend::fit::TrainDevice::Cpu {
            device.candle()?;
        }
        let simulated = [RigKind::Virtual, RigKind::Window];
        let runs = match (&a.data, &file) {
            (None, Some(f)) => Some((Runs::new(&f.paths.data), f.calibration.keep_runs)),
            _ => None,
        };
        // With runs, the data root is the run's, chosen when the calibration starts.
        let data = a
            .data
            .unwrap_or_else(|| PathBuf::from("compend-calibration"));
        let out = a
            .out
            .or_else(|| file.as_ref().map(|f| f.paths.model.clone()))
            .unwrap_or_else(|| data.join("model"));
        let k = &c.calibration;
        let calibration = CalibrationConfig {
            method,
            ntrain,
            ntest: a.ntest.unwrap_or(k.ntest),
            verify: a.verify.unwrap_or(k.verify),
            min_gain_db: a.min_gain.unwrap_or(k.min_gain_db),
            average: a.average.unwrap_or(k.average),
            network: a.network.unwrap_or(k.network),
            climb_gain_db: a.climb_gain.unwrap_or(k.climb_gain_db),
            climb_iters: a.climb_iters.or(k.climb_iters),
            device,
            loop_images: asked,
            refresh_hz: a.refresh_hz.or(k.refresh_hz),
            ..k.clone()
        };
        Ok(Settings {
            camera_size: a
                .camera_size
                .or(r.camera_size.filter(|_| from(&[RigKind::Camera]))),
            monitor: a.monitor.or_else(|| {
                r.monitor
                    .clone()
                    .filter(|_| from(&[RigKind::Window, RigKind::Camera]))
            }),
            rig_latency_ms: a
                .rig_latency_ms
                .or(r.latency_ms.filter(|_| from(&simulated))),
            rig_fps: a.rig_fps.or(r.camera_fps.filter(|_| from(&simulated))),
            rig_clock: a.rig_clock,
            rig_camera: a.rig_camera.or(r.camera_size.filter(|_| from(&simulated))),
            projector: a.projector.or(r.projector.filter(|_| from(&simulated))),
            rig,
            camera,
            data,
            out,
            iters: match method {
                MethodChoice::Auto => calibration.climb_iters,
                MethodChoice::Rung(_) => a.iters,
            },
            calibration,
            base_rig: r.clone(),
            rig_from_file,
            seed: a.seed.unwrap_or(r.seed),
            json: a.json,
            runs,
            state: file.map(|f| f.paths.state),
        })
    }
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
    let mut args = Settings::new(args)?;
    let out = args.out.clone();
    // Before any work: where the model goes must take a model, and the numbers must make sense.
    compend::model::store::check_output(&out)?;
    check_counts(&args)?;
    // A service on this configuration drives its rig and installs into its model path: not
    // while it runs, and it does not start while this does. A state directory not made yet has
    // no service.
    let _lock = match &args.state {
        Some(state) if state.is_dir() => {
            let lock = compend::service::lock_state_if_held(state, "calibrate")?;
            if lock.is_none() {
                tracing::warn!(
                    "{}: this user cannot read the state directory's lock file, so cannot tell \
                     whether a service runs on this configuration",
                    state.display()
                );
            }
            lock
        }
        _ => None,
    };
    // One calibration at a time in a data folder given by --data: a second would mix its
    // captures with this one's and both would install.
    let _data_lock = match args.runs {
        None => Some(compend::service::lock_data(&args.data)?),
        Some(_) => None,
    };
    // And a model path in a service's state directory (or a locked data folder), named by
    // --out.
    let held: Vec<&Path> = [
        args.state.as_deref().filter(|_| _lock.is_some()),
        _data_lock.as_ref().map(|_| args.data.as_path()),
    ]
    .into_iter()
    .flatten()
    .collect();
    let _model_lock = super::lock_model_state(&out, &held, "calibrate")?;
    let Some((runs, keep)) = args.runs.take() else {
        return dispatch(&args, &out);
    };
    let rig = match (&args.rig, &args.camera) {
        (Some(r), _) => r.clone(),
        (None, Some(c)) => format!("camera:{}", c.display()),
        (None, None) => String::new(),
    };
    let run = runs.begin(&rig, std::time::SystemTime::now())?;
    if run.resumed {
        eprintln!(
            "calibrate: resuming the interrupted run {}",
            run.data.display()
        );
    }
    args.data = run.data;
    let result = dispatch(&args, &out);
    // A failed operation (a camera gone, a full disk) leaves the run marked, to resume; a
    // finished or refused one is over.
    if result
        .as_ref()
        .err()
        .is_none_or(|e| super::exit_code(e) != 1)
    {
        runs.end();
        runs.prune(keep);
    }
    result
}

/// Calibrates the rig the settings name and installs the model into `out`.
fn dispatch(args: &Settings, out: &Path) -> Result<()> {
    let Some(rig) = &args.rig else {
        let Some(device) = args.camera.clone() else {
            return Err(compend::Error::Input(
                "no rig to calibrate: give --rig, --camera or a --config with a [rig]".into(),
            )
            .into());
        };
        if args.rig_camera.is_some() || args.projector.is_some() {
            return Err(compend::Error::Input(
                "--rig-camera and --projector size the virtual rig; with --camera, \
                 --camera-size sets the capture size and the projector is the monitor's"
                    .into(),
            )
            .into());
        }
        let rig = RigConfig {
            kind: RigKind::Camera,
            camera: Some(device),
            camera_size: args.camera_size,
            ..rig_config(args)
        };
        return calibrate_rig(args, out, &rig);
    };
    if args.camera_size.is_some() {
        return Err(compend::Error::Input(
            "--camera-size is the V4L2 camera's capture size; the virtual camera's is \
             --rig-camera"
                .into(),
        )
        .into());
    }
    let (kind, scene) = parse_rig(rig)?;
    if kind == RigKind::Virtual && args.monitor.is_some() {
        return Err(compend::Error::Input(
            "--monitor: only `--rig window` shows the patterns on a monitor".into(),
        )
        .into());
    }
    let rig = RigConfig {
        kind,
        scene,
        ..rig_config(args)
    };
    calibrate_rig(args, out, &rig)
}

/// The `[rig]` of this calibration (a virtual one): the configuration's, with the flags written
/// over it.
fn rig_config(args: &Settings) -> RigConfig {
    RigConfig {
        seed: args.seed,
        camera_size: args.rig_camera,
        projector: args.projector,
        monitor: args.monitor.clone(),
        camera_fps: args.rig_fps,
        latency_ms: args.rig_latency_ms,
        ..args.base_rig.clone()
    }
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

/// Opens the rig `rig` ([`compend::rigs::open`], as the service opens its own), calibrates it
/// and installs the model into `out`.
fn calibrate_rig(args: &Settings, out: &Path, rig: &RigConfig) -> Result<()> {
    let given = if args.rig_from_file {
        Given::File
    } else {
        Given::Flags
    };
    let monitor = args.monitor.as_deref().unwrap_or("the primary monitor");
    match rigs::open(rig, args.rig_clock, given)? {
        Opened::Virtual { rig: sim, scene } if sim.outputs() > 1 => {
            eprintln!(
                "calibrate: virtual rig {:?}, a set of {} projectors ({}) into {}",
                rig.scene,
                sim.outputs(),
                describe_camera(&scene),
                args.data.display()
            );
            let displays = (0..sim.outputs())
                .map(|k| sim.output(k))
                .collect::<compend::Result<Vec<_>>>()?;
            let mut camera = sim;
            calibrate_set_on(
                displays,
                &mut camera,
                args,
                scene.projector.size(),
                rig,
                out,
            )
        }
        Opened::WindowSet {
            windows,
            mut camera,
            scene,
        } => {
            eprintln!(
                "calibrate: a set of {} projector windows {} at {} Hz on monitors {} ({}), \
                 virtual camera on scene {:?} ({}) into {}",
                windows.borrow().monitors().len(),
                scene.projector.size(),
                windows.borrow().refresh_hz(),
                windows.borrow().monitors().join(", "),
                windows.borrow().context().describe(),
                rig.scene,
                describe_camera(&scene),
                args.data.display()
            );
            let displays = compend::window::ProjectorWindows::outputs(&windows);
            let done = calibrate_set_on(
                displays,
                &mut camera,
                args,
                scene.projector.size(),
                rig,
                out,
            );
            report_set_timing(&windows.borrow(), &camera, &scene);
            done
        }
        #[cfg(target_os = "linux")]
        Opened::CameraSet {
            windows,
            mut camera,
            device,
            controls,
        } => {
            for line in controls {
                eprintln!("calibrate: {}: {line}", device.display());
            }
            let size = windows.borrow().sizes()[0];
            eprintln!(
                "calibrate: a set of {} projector windows {size} at {} Hz on monitors {} ({}), \
                 camera {} ({}) into {}",
                windows.borrow().monitors().len(),
                windows.borrow().refresh_hz(),
                windows.borrow().monitors().join(", "),
                windows.borrow().context().describe(),
                device.display(),
                FrameSource::size(&camera),
                args.data.display()
            );
            let displays = compend::window::ProjectorWindows::outputs(&windows);
            calibrate_set_on(displays, &mut camera, args, size, rig, out)
        }
        Opened::Virtual { rig: sim, scene } => {
            eprintln!(
                "calibrate: virtual rig {:?} (projector {}, {}) into {}",
                rig.scene,
                scene.projector.size(),
                describe_camera(&scene),
                args.data.display()
            );
            // Its projector plays through no GPU: the climb's live pass is weighed only when
            // asked, on this machine's GPU.
            let live = match args.calibration.refresh_hz {
                Some(hz) if hz > 0.0 && args.calibration.method == MethodChoice::Auto => {
                    let ctx = compend::gpu::GpuContext::new().with_context(|| {
                        format!(
                            "opening this machine's GPU to time the climb's live pass at {hz} Hz \
                             (--refresh-hz, or the configuration's refresh_hz)"
                        )
                    })?;
                    Some(live_pass(ctx, hz)?)
                }
                _ => None,
            };
            let (mut display, mut camera) = (sim.clone(), sim);
            let done = calibrate_on(
                &mut display,
                &mut camera,
                args,
                scene.projector.size(),
                rig,
                live,
            )?;
            install(done, out)
        }
        Opened::Window {
            mut win,
            mut camera,
            scene,
        } => {
            let size = DisplaySink::size(&win);
            eprintln!(
                "calibrate: projector window {size} at {} Hz on {monitor} ({}), virtual camera \
                 on scene {:?} ({}) into {}",
                win.refresh_hz(),
                win.context().describe(),
                rig.scene,
                describe_camera(&scene),
                args.data.display()
            );
            let live = window_live_pass(args, &win)?;
            let done = calibrate_on(&mut win, &mut camera, args, size, rig, live);
            report_window_timing(&win, &camera, &scene);
            if let Ok(d) = &done {
                let l = &scene.latency;
                let trials = &d.record.latency.trials;
                let worst = trials.iter().copied().max().unwrap_or(0);
                eprintln!(
                    "calibrate: measured latency {worst} exposures = {:.0} ms at {} fps (scene \
                     delay {:.0} ms)",
                    worst as f64 / l.fps * 1e3,
                    l.fps,
                    l.delay_frames as f64 / l.fps * 1e3
                );
            }
            drop(camera);
            install(done?, out)
        }
        #[cfg(target_os = "linux")]
        Opened::Camera {
            mut win,
            mut camera,
            device,
            controls,
        } => {
            for line in controls {
                eprintln!("calibrate: {}: {line}", device.display());
            }
            let size = DisplaySink::size(&win);
            eprintln!(
                "calibrate: projector window {size} at {} Hz on {monitor} ({}), camera {} ({}) \
                 into {}",
                win.refresh_hz(),
                win.context().describe(),
                device.display(),
                FrameSource::size(&camera),
                args.data.display()
            );
            let live = window_live_pass(args, &win)?;
            let done = calibrate_on(&mut win, &mut camera, args, size, rig, live);
            install(done?, out)
        }
    }
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

/// How presenting on a set's windows and the camera went, as `key=value` pairs.
fn report_set_timing(
    windows: &compend::window::ProjectorWindows,
    camera: &WindowCamera,
    scene: &Scene,
) {
    let w = windows.show_timing();
    let p = windows.presents();
    eprintln!(
        "calibrate: windows: shows={} skipped={} refresh_hz={} presented={:?} together={} \
         out_of_step={} skew_ms_max={:.2} readback_ms={:.2}/{:.2}",
        w.shows,
        w.skipped,
        windows.refresh_hz(),
        p.presented,
        p.together,
        p.out_of_step,
        p.skew_ms_max,
        w.readback_ms_mean,
        w.readback_ms_max
    );
    let c = camera.timing();
    eprintln!(
        "calibrate: camera: fps={} exposures={} delivered={} dropped={} changes={} \
         lag_ms={:.1}..{:.1} render_ms={:.2}",
        scene.latency.fps,
        c.exposures,
        c.delivered,
        c.dropped,
        c.changes,
        c.lag_ms_min,
        c.lag_ms_max,
        c.render_ms_mean
    );
}

/// `auto`'s climb weighed on the projector window's GPU, at `--refresh-hz` or the window's
/// refresh rate; `None` for another method or `--refresh-hz 0`.
fn window_live_pass(
    args: &Settings,
    win: &ProjectorWindow,
) -> Result<Option<Arc<dyn compend::fit::LivePass>>> {
    match args.calibration.refresh_hz.unwrap_or(win.refresh_hz()) {
        hz if hz > 0.0 && args.calibration.method == MethodChoice::Auto => {
            Ok(Some(live_pass(win.context().clone(), hz)?))
        }
        _ => Ok(None),
    }
}

/// The timer of a climb's live pass on `ctx` at `hz`, said on stderr.
fn live_pass(ctx: compend::gpu::GpuContext, hz: f64) -> Result<Arc<dyn compend::fit::LivePass>> {
    eprintln!(
        "calibrate: auto climbs only to a rung whose live pass on {} takes at most {} ms ({} \
         of one refresh period at {} Hz)",
        ctx.describe(),
        compend::record::readable(compend::fit::LIVE_SHARE * 1e3 / hz),
        compend::fit::LIVE_SHARE,
        compend::record::readable(hz)
    );
    Ok(Arc::new(compend::gpu::live::GpuLivePass::new(ctx, hz)?))
}

/// Calibrates a set of projectors (`displays`, one per projector in the set's order, seen by
/// `camera`), prints the set's record and installs its model into `out` if the whole set
/// verified.
fn calibrate_set_on<D: DisplaySink, C: FrameSource + ?Sized>(
    displays: Vec<D>,
    camera: &mut C,
    args: &Settings,
    projector: ImageSize,
    rig: &RigConfig,
    out: &Path,
) -> Result<()> {
    let opts = rigs::calibration_options(rig, &args.calibration, None, projector, None, None);
    let report = super::progress::Progress::new("calibrate", args.json);
    let mut progress = |stage: &str, done: usize, total: usize| report.update(stage, done, total);
    let done = calibrate::set::calibrate_set(displays, camera, &args.data, &opts, &mut progress)
        .with_context(|| format!("calibrating the set into {}", args.data.display()))?;
    report.finish();
    print_set_record(&done, args.json)?;
    let n = done.model.models.len();
    calibrate::set::install_set(done, out)
        .with_context(|| format!("installing the set's model into {}", out.display()))?;
    eprintln!(
        "calibrate: installed the joint model of {n} projectors into {}",
        out.display()
    );
    Ok(())
}

/// Each projector's calibration and the whole set's verification on stderr; the set's record
/// on stdout with `--json`.
fn print_set_record(done: &calibrate::set::CalibratedSet, json: bool) -> Result<()> {
    let r = &done.record;
    for (k, m) in done.model.models.iter().enumerate() {
        if let Some(c) = &m.meta.calibration {
            let v = &c.verification;
            eprintln!(
                "calibrate: projector {}: {} captures, latency {:?} exposures, {:.1} s; alone \
                 in its own area {:.2} dB compensated, {:.2} dB uncompensated",
                k + 1,
                c.captured,
                c.latency.trials,
                r.projector_seconds.get(k).copied().unwrap_or(f64::NAN),
                v.psnr,
                v.uncompensated_psnr
            );
        }
    }
    let v = &r.verification;
    let alone = v
        .alone_psnr
        .iter()
        .enumerate()
        .map(|(k, p)| format!("projector {} alone {p:.2} dB", k + 1))
        .collect::<Vec<_>>()
        .join(", ");
    eprintln!(
        "calibrate: the whole set on {} test images in its displayable area {}: {:.2} dB / SSIM \
         {:.3} jointly; {alone}: {:+.2} dB over the best alone (needs {:+.2})",
        v.images, r.area, v.psnr, v.ssim, v.gain_db, v.required_gain_db
    );
    match &v.seam {
        Some(s) => eprintln!(
            "calibrate: seam figure {:.2} (error along the overlap edges {:.2e} against {:.2e} \
             away, residual steps {:.2e} against {:.2e}; at most {} passes)",
            s.ratio(),
            s.band_mse,
            s.away_mse,
            s.band_gradient,
            s.away_gradient,
            v.seam_limit
        ),
        None => eprintln!("calibrate: the projectors do not overlap in the area: no seam figure"),
    }
    eprintln!(
        "calibrate: camera curves of the projectors' models differ by {:.3}; seconds: {} \
         projectors, set verification {:.1}, total {:.1}",
        r.camera_gamma_spread,
        r.projector_seconds
            .iter()
            .map(|s| format!("{s:.1}"))
            .collect::<Vec<_>>()
            .join(" + "),
        r.verification_seconds,
        r.total_seconds
    );
    if json {
        println!("{}", serde_json::to_string(r)?);
    }
    Ok(())
}

/// Runs the calibration flow on a display and a camera and prints its record.
fn calibrate_on<D: DisplaySink + ?Sized, C: FrameSource + ?Sized>(
    display: &mut D,
    camera: &mut C,
    args: &Settings,
    projector: ImageSize,
    rig: &RigConfig,
    live: Option<Arc<dyn compend::fit::LivePass>>,
) -> Result<Calibrated> {
    let mut opts = rigs::calibration_options(rig, &args.calibration, None, projector, live, None);
    // `--iters`: the iterations of a CompenNet++ rung asked for by name (the configuration
    // has only the climb's).
    if let MethodChoice::Rung(_) = opts.method {
        opts.iters = args.iters;
    }
    let report = super::progress::Progress::new("calibrate", args.json);
    let mut progress = |stage: &str, done: usize, total: usize| report.update(stage, done, total);
    let done = calibrate::calibrate(display, camera, &args.data, &opts, &mut progress)
        .with_context(|| format!("calibrating into {}", args.data.display()))?;
    report.finish();
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
         found on disk, {} retaken{}",
        r.latency.trials,
        r.latency.settle_frames,
        r.captured,
        r.resumed,
        r.retakes,
        match r.reconnects {
            0 => String::new(),
            n => format!("; the camera went away and was reopened {n} times"),
        }
    );
    eprintln!(
        "calibrate: seconds: exposure {:.1}, latency {:.1}, patterns {:.1}, captures {:.1}, \
         training {:.1}, verification {:.1}, total {:.1}",
        s.exposure, s.latency, s.patterns, s.captures, s.training, s.verification, s.total
    );
    if let Some(f) = r.capture_floor.filter(|f| f.fps > 0.0) {
        eprintln!(
            "calibrate: {} captures took {:.1} s against a floor of {:.1} s ({} exposures of \
             latency and averaging at {:.1} fps): {:.2}× the floor; the whole calibration \
             {:.2}× it",
            f.captures,
            f.seconds,
            f.floor_seconds(),
            f.frames,
            f.fps,
            f.seconds / f.floor_seconds().max(1e-9),
            s.total / f.floor_seconds().max(1e-9)
        );
    }
    if let Some(u) = &r.unreachable {
        eprintln!("calibrate: {}", u.line());
    }
    if let Some(curve) = &r.sampling {
        eprintln!("calibrate: {}", curve.line());
    }
    if let Some(choice) = &r.closed_loop {
        eprintln!("calibrate: {}", choice.line());
    }
    for line in done
        .model
        .meta
        .training
        .auto
        .iter()
        .flat_map(compend::fit::evidence_lines)
    {
        eprintln!("calibrate: {line}");
    }
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
    let model = calibrate::install(done, out)
        .with_context(|| format!("installing the model into {}", out.display()))?;
    eprintln!(
        "calibrate: installed {} into {}",
        model.meta.method,
        out.display()
    );
    Ok(())
}

/// The counts must allow a fit and a verification.
fn check_counts(a: &Settings) -> compend::Result<()> {
    let c = &a.calibration;
    let bad = |what: String| Err(compend::Error::Input(what));
    if c.ntrain.most() < compend::fit::MIN_TRAIN {
        return bad(format!(
            "--ntrain {}: at least {} training images are needed",
            c.ntrain,
            compend::fit::MIN_TRAIN
        ));
    }
    if c.ntest == 0 || c.verify == 0 || c.verify > c.ntest {
        return bad(format!(
            "--ntest {} / --verify {}: the verification projects 1 to NTEST test images",
            c.ntest, c.verify
        ));
    }
    if c.average == 0 {
        return bad("--average 0: at least one frame per capture".into());
    }
    if !(c.min_gain_db.is_finite()) {
        return bad(format!(
            "--min-gain {}: expected a number of dB",
            c.min_gain_db
        ));
    }
    if !c.climb_gain_db.is_finite() {
        return bad(format!(
            "--climb-gain {}: expected a number of dB",
            c.climb_gain_db
        ));
    }
    if a.iters == Some(0) {
        let flag = match c.method {
            MethodChoice::Auto => "--climb-iters",
            MethodChoice::Rung(_) => "--iters",
        };
        return bad(format!("{flag} 0: expected at least 1"));
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
