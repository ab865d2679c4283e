//! `compend play`: live compensation of a video source on the projector window, or on the
//! virtual rig (`--rig virtual[:SCENE]`), which replaces the window by the rig's projector and
//! writes what its camera sees.

use std::path::PathBuf;

use anyhow::{Context, Result};
use compend::device::DisplaySink;
use compend::fov::DisplayRange;
use compend::gpu::GpuContext;
use compend::model::Model;
use compend::output::{MediaOutput, OutputSpec, Teed};
use compend::player::{Headless, PlayStats, Player, Refresh, Screen, ViewSink, WatchedSink};
use compend::rig::{self, Phase, Simulator, VirtualRig, scene};
use compend::source::{self, AudioOut, FeedMode, SourceSpec, VideoSource};
use compend::window::ProjectorWindow;

use super::play_flags::{check_out, mark_out, parse_rig};

#[derive(clap::Args, Debug)]
#[command(after_help = sources_and_outputs_help())]
pub struct Args {
    /// The model directory (any method: linear, linear-sl, the CompenNet++ family). Without it,
    /// the running service (`compend serve`) is asked to play the source with its model.
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// Without --model: the service's socket (or --config, its configuration file).
    #[command(flatten)]
    pub client: super::serve::ClientArgs,
    /// What to play (spellings below). Required with --model; without it, the service plays
    /// this source, or its configured one when it is left out.
    #[arg(long, value_name = "SRC")]
    pub source: Option<String>,
    /// Stop after N display refreshes [default: when the source ends; on the window, still
    /// images and slideshows play until the window is closed or Escape is pressed].
    #[arg(long, value_name = "N")]
    pub frames: Option<u64>,
    /// Play on the virtual rig instead of the projector window: `virtual` (the rig the model was
    /// calibrated on, from its setup's rig.json) or `virtual:SCENE` (a built-in scene or scene
    /// JSON file, at the model's camera size).
    #[arg(long, value_name = "virtual[:SCENE]")]
    pub rig: Option<String>,
    /// Folder for the virtual camera's views (cam_NNNNNN.png, one per shown frame, numbered by
    /// source frame) and play.json (the frame counts).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Display refresh rate of the virtual rig, Hz (the window follows the monitor's vsync).
    #[arg(long, default_value_t = 60.0)]
    pub fps: f64,
    /// `display`: real time at the refresh rate, the newest frame wins and dropped frames are
    /// counted; `source`: every source frame is shown once, as fast as the pipeline goes
    /// (offline rendering on the virtual rig).
    #[arg(long, value_enum, default_value_t = Pace::Display)]
    pub pace: Pace,
    /// The projector's monitor for the window: its name or index (the error for an unknown one
    /// lists them) [default: the primary monitor]. A set of projectors names one per projector,
    /// in the set's order: `--monitor HDMI-1,HDMI-2`.
    #[arg(long)]
    pub monitor: Option<String>,
    /// Seed of the virtual rig's texture and noise [default: the calibration record's, else 0].
    #[arg(long)]
    pub seed: Option<u64>,
    /// Print the frame counts as one JSON object on stdout.
    #[arg(long)]
    pub json: bool,
    /// Also send the compensated frames (the projector canvas) to a file or a GStreamer
    /// pipeline (spellings below). A set of projectors takes one per projector, in the set's
    /// order: `--to file:left.mp4 --to file:right.mp4`.
    #[arg(long, value_name = "OUT", action = clap::ArgAction::Append)]
    pub to: Vec<String>,
    /// With --to: no projector window, only the output (offline rendering of a film with
    /// --pace source).
    #[arg(long, requires = "to", conflicts_with = "rig")]
    pub no_window: bool,
    /// With --no-window: the projector's size, WxH [default: the one the model was calibrated
    /// for].
    #[arg(long, value_name = "WxH", requires = "no_window", value_parser = super::sim::parse_size)]
    pub projector: Option<compend::raster::ImageSize>,
    /// Where a film's sound goes: `auto` (PulseAudio or PipeWire, else ALSA's default
    /// device), a GStreamer audio sink (`alsasink device=hw:1`, `pulsesink`, `jackaudiosink`)
    /// or `none`. Sound plays only with --pace display.
    #[arg(long, value_name = "SINK", default_value = "auto")]
    pub audio: String,
    /// A trim of the sound's delay, ms, added to the measured picture latency (positive: the
    /// sound later).
    #[arg(
        long,
        value_name = "MS",
        default_value_t = 0.0,
        allow_negative_numbers = true
    )]
    pub audio_delay: f64,
}

/// The source and output spellings under `compend play --help`.
fn sources_and_outputs_help() -> String {
    format!("{}\n\n{}", compend::source::HELP, compend::output::HELP)
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Pace {
    Display,
    Source,
}

pub fn run(args: Args) -> Result<()> {
    let Some(model_dir) = &args.model else {
        return super::serve::simple(
            &args.client,
            compend::service::protocol::Request::Play {
                source: args.source.clone(),
            },
        );
    };
    if !(args.fps.is_finite() && args.fps > 0.0) {
        return Err(
            compend::Error::Input(format!("--fps must be positive, got {}", args.fps)).into(),
        );
    }
    let Some(source_text) = args.source.as_deref() else {
        return Err(compend::Error::Input(
            "--source is required with --model (what to play; spellings in compend play --help)"
                .into(),
        )
        .into());
    };
    let spec = SourceSpec::parse(source_text)?;
    let to = args
        .to
        .iter()
        .map(|t| OutputSpec::parse(t))
        .collect::<compend::Result<Vec<_>>>()?;
    if !(args.audio_delay.is_finite() && args.audio_delay.abs() <= 10_000.0) {
        return Err(compend::Error::Input(format!(
            "--audio-delay {}: expected milliseconds from -10000 to 10000",
            args.audio_delay
        ))
        .into());
    }
    // Media is probed (its first frame decoded): a bad file fails here, before the GPU, and
    // an output rendered offline takes the film's frame rate.
    let probed = match &spec {
        SourceSpec::Media(m) => Some(source::media::probe(m, source::MEDIA_CHECK_TIMEOUT)?),
        _ => None,
    };
    // The output's frame rate: offline the source's own (a film's, a pattern's), live the
    // display's.
    let source_fps = match (&spec, &probed) {
        (_, Some(p)) => p.fps,
        (SourceSpec::Pattern { fps, .. }, _) => Some(*fps),
        _ => None,
    };
    if compend::model::set::SetModel::is_set(model_dir) {
        let set = super::play_set::SetPlay {
            rig: args.rig.as_deref(),
            frames: args.frames,
            out: args.out.as_deref(),
            seed: args.seed,
            json: args.json,
            monitor: args.monitor.as_deref(),
            to,
            no_window: args.no_window,
            projector: args.projector,
            output_fps: source_fps.unwrap_or(args.fps),
        };
        return super::play_set::play_set(&set, model_dir, &spec);
    }
    if to.len() > 1 {
        return Err(compend::Error::Input(format!(
            "--to given {} times: one projector's frames go to one output (a set of projectors \
             takes one per projector)",
            to.len()
        ))
        .into());
    }
    let to = to.into_iter().next();
    if let Some(dir) = &args.out {
        check_out(dir)?;
    }
    let model = Model::load(model_dir)?;
    let rig = args.rig.as_deref().map(parse_rig).transpose()?;
    // The source is opened before the GPU (below) so a bad source fails fast.
    let audio = AudioOut {
        sink: (args.audio != "none").then(|| args.audio.clone()),
        delay_ms: args.audio_delay,
    };
    let source = source::open_with(&spec, &audio)?;
    let mode = match args.pace {
        Pace::Display => FeedMode::Latest,
        Pace::Source => FeedMode::Queue,
    };
    let out = to.map(|spec| Output {
        spec,
        offline_fps: source_fps.unwrap_or(args.fps),
    });
    let stats = match rig {
        Some(scene_name) => play_virtual(&args, &model, scene_name.as_deref(), source, mode, out)?,
        None if args.no_window => play_headless(&args, &model, source, mode, out)?,
        None => play_window(&args, &model, source, mode, out)?,
    };
    eprintln!("play: {}", stats.summary());
    let json = serde_json::to_string(&stats)?;
    if let Some(dir) = &args.out {
        mark_out(dir)?;
        compend::files::write_atomically(&dir.join("play.json"), format!("{json}\n").as_bytes())?;
    }
    if args.json {
        println!("{json}");
    }
    Ok(())
}

/// A media output (`--to`) and the frame rate it is written at offline.
struct Output {
    spec: OutputSpec,
    offline_fps: f64,
}

/// Plays `player` on `screen`, its frames also to `out` when given (started for `size`
/// projector pixels at the display's rate live, the source's offline).
fn run_teed<S: Screen + ?Sized>(
    player: &mut Player,
    screen: &mut S,
    out: Option<Output>,
    size: compend::raster::ImageSize,
    frames: Option<u64>,
) -> Result<PlayStats> {
    let Some(out) = out else {
        return Ok(player.run(screen, frames)?);
    };
    let live = player.feed.mode() == FeedMode::Latest;
    let fps = if live {
        match screen.refresh() {
            Refresh::Vsync(hz) | Refresh::Timer(hz) => hz,
        }
    } else {
        out.offline_fps
    };
    let output = MediaOutput::start(&out.spec, size, fps, live)?;
    eprintln!(
        "play: compensated frames also to {} at {fps:.3} fps",
        out.spec
    );
    let mut teed = Teed::new(screen, output);
    Ok(player.run(&mut teed, frames)?)
}

/// Plays on the projector window until the source ends (streams), `--frames`, or the window is
/// closed.
fn play_window(
    args: &Args,
    model: &Model,
    source: Box<dyn VideoSource>,
    mode: FeedMode,
    out: Option<Output>,
) -> Result<PlayStats> {
    let mut win = ProjectorWindow::open(args.monitor.as_deref())?;
    let size = DisplaySink::size(&win);
    let range = model.display_range();
    let mut player = Player::start(win.context(), model, size, range, source, mode)?;
    eprintln!(
        "play: {} on the projector window {} at {:.1} Hz ({})",
        player.feed.describe(),
        size,
        win.refresh_hz(),
        win.context().describe()
    );
    run_teed(&mut player, &mut win, out, size, args.frames)
}

/// Plays with no display, only to the output: at the model's projector size (its calibration
/// record's), paced at `--fps` live, as fast as it goes offline.
fn play_headless(
    args: &Args,
    model: &Model,
    source: Box<dyn VideoSource>,
    mode: FeedMode,
    out: Option<Output>,
) -> Result<PlayStats> {
    let size = super::model_projector(model, args.projector)?;
    let ctx = GpuContext::new()?;
    let range = model.display_range();
    let mut player = Player::start(&ctx, model, size, range, source, mode)?;
    eprintln!(
        "play: {} to the output only, projector canvas {} ({})",
        player.feed.describe(),
        size,
        ctx.describe()
    );
    let mut screen = Headless::new(&ctx, args.fps);
    run_teed(&mut player, &mut screen, out, size, args.frames)
}

/// Plays on the virtual rig (`scene_name`, or the rig the model was calibrated on) at `--fps`,
/// writing the camera's views to `--out` when given.
fn play_virtual(
    args: &Args,
    model: &Model,
    scene_name: Option<&str>,
    source: Box<dyn VideoSource>,
    mode: FeedMode,
    out: Option<Output>,
) -> Result<PlayStats> {
    let (rig, range) = virtual_rig(model, scene_name, args.seed)?;
    let ctx = GpuContext::new()?;
    let sim = rig.simulator();
    let mut player = Player::start(&ctx, model, sim.projector_size(), range, source, mode)?;
    let placement = player.pass.placement();
    eprintln!(
        "play: {} on the virtual rig (scene {:?}, camera {}, projector {}; area {}, canvas \
         {}) with {}",
        args.source.as_deref().unwrap_or_default(),
        sim.scene().name,
        sim.camera_size(),
        placement.projector_size,
        placement.area,
        placement.canvas,
        ctx.describe()
    );
    let views: ViewSink = match &args.out {
        Some(dir) => {
            mark_out(dir)?;
            let dir = dir.clone();
            Box::new(move |seq, _, img| {
                compend::pngio::write_rgb(&dir.join(format!("cam_{seq:06}.png")), img)
            })
        }
        None => Box::new(|_, _, _| Ok(())),
    };
    let size = placement.projector_size;
    let mut screen = WatchedSink::new(&ctx, args.fps, rig.clone(), rig, views);
    run_teed(&mut player, &mut screen, out, size, args.frames)
}

/// The rig the model was calibrated on (its setup's rig.json), or `scene` at the model's camera
/// size; with the display range desired images were scaled into there.
pub(super) fn virtual_rig(
    model: &Model,
    scene_name: Option<&str>,
    seed: Option<u64>,
) -> Result<(VirtualRig, DisplayRange)> {
    let record = model
        .meta
        .training
        .setup
        .as_deref()
        .and_then(|setup| rig::export::read_record(setup).ok());
    let cam = model.camera_size();
    let (scene, record_seed, range) = match (scene_name, &record) {
        (None, Some(r)) => (r.scene.clone(), r.seed, r.desired_range),
        (None, None) => {
            return Err(compend::Error::Input(format!(
                "--rig virtual: model {} was not calibrated on the virtual rig (no rig.json in its \
                 setup); name a scene: --rig virtual:SCENE ({})",
                model.meta.method,
                rig::BUILTIN.join(", ")
            ))
            .into());
        }
        (Some(name), r) => {
            let s = scene::load(name)?;
            // The record's projector resolution when it is the same scene, else the scene's.
            let prj = match r {
                Some(r) if r.scene.name == s.name => r.scene.projector.size(),
                _ => s.projector.size(),
            };
            let same = r.as_ref().filter(|r| r.scene.name == s.name);
            (
                s.with_resolution(cam, prj),
                same.map_or(0, |r| r.seed),
                same.map_or_else(|| model.display_range(), |r| r.desired_range),
            )
        }
    };
    scene.validate()?;
    if scene.camera.size() != cam {
        return Err(compend::Error::Input(format!(
            "the model expects {cam} camera images, the virtual rig's camera is {}",
            scene.camera.size()
        ))
        .into());
    }
    let sim = Simulator::new(&scene, seed.unwrap_or(record_seed), Phase::Calibration)
        .with_context(|| format!("preparing virtual rig scene {:?}", scene.name))?;
    let mut rig = VirtualRig::from_simulator(sim);
    // A model made by `compend calibrate` saw the camera at the exposure it chose.
    if let Some(e) = model
        .meta
        .calibration
        .as_ref()
        .and_then(|c| c.exposure.as_ref())
    {
        compend::device::FrameSource::set_exposure(&mut rig, e.chosen)?;
    }
    // An ideal camera for playback: no delay, no drops, one exposure per shown frame.
    rig.set_latency(rig::scene::Latency {
        fps: 60.0,
        delay_frames: 0,
        drop_rate: 0.0,
    })?;
    Ok((rig, range))
}
