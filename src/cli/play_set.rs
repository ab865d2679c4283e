//! `compend play --model SET`: a set of projectors' joint model plays a source, every frame
//! through the joint pass on the GPU (`gpu::joint::JointPass`).
//!
//! - `--monitor A,B` (one per projector, in the set's order): one fullscreen window per
//!   projector's monitor on one GPU device (`window::ProjectorWindows`), every output showing
//!   the same source frame in the same refresh, in real time; `--json` reports what each output
//!   presented and whether any fell a frame behind.
//! - `--rig virtual[:SCENE]`: each projector's image shown on its output of the set's virtual
//!   rig, the camera's view of the whole written to `--out` (cam_NNNNNN.png, numbered by source
//!   frame). Offline: every source frame is shown once.
//! - `--no-window`: no display, every source frame once, offline.
//!
//! `--to OUT`, once per projector in the set's order, sends each projector's compensated frames
//! (its canvas, projector pixels) to a file or a GStreamer pipeline as well (`--no-window`:
//! instead): offline at the source's frame rate, live on the windows at their refresh.

use std::path::Path;

use anyhow::{Context, Result};
use compend::device::{DisplaySink, FrameSource};
use compend::model::set::SetModel;
use std::time::Duration;

use compend::output::{OutputSpec, SetOutputs};
use compend::raster::{CamImage, ImageSize, PrjImage, Rect};
use compend::record::set::SetRecord;
use compend::rig::{VirtualRig, scene};
use compend::source::{self, Next, SourceSpec};

use super::play_flags::{check_out, mark_out, parse_rig};

/// `play`'s flags a set's playback reads.
pub struct SetPlay<'a> {
    /// `--rig`.
    pub rig: Option<&'a str>,
    /// `--frames`: stop after this many source frames.
    pub frames: Option<u64>,
    /// `--out`: the camera's views.
    pub out: Option<&'a Path>,
    pub seed: Option<u64>,
    pub json: bool,
    /// `--monitor`: the projectors' monitors, comma-separated, in the set's order.
    pub monitor: Option<&'a str>,
    /// `--to`: one output per projector, in the set's order, or none.
    pub to: Vec<OutputSpec>,
    /// `--no-window`: only the outputs.
    pub no_window: bool,
    /// `--projector`: the projectors' size with `--no-window`.
    pub projector: Option<ImageSize>,
    /// The outputs' frame rate offline (the source's, else `--fps`).
    pub output_fps: f64,
}

/// Starts one output per projector ([`SetOutputs::start`]) and says where they go.
fn start_outputs(
    specs: &[OutputSpec],
    n: usize,
    size: ImageSize,
    fps: f64,
    live: bool,
) -> Result<Option<SetOutputs>> {
    let outputs = SetOutputs::start(specs, n, size, fps, live)?;
    if outputs.is_some() {
        let list: Vec<String> = specs.iter().map(|s| s.to_string()).collect();
        eprintln!(
            "play: each projector's compensated frames to {} at {fps:.3} fps",
            list.join(", ")
        );
    }
    Ok(outputs)
}

/// Each projector's image of the joint pass (its lattice) on its canvas of `size`.
fn canvases(
    pass: &compend::gpu::joint::JointPass,
    ctx: &compend::gpu::GpuContext,
    size: ImageSize,
) -> Result<Vec<PrjImage>> {
    Ok(pass
        .read(ctx)?
        .iter()
        .map(|net| compend::playback::place_on_canvas(net, Rect::covering(size), size))
        .collect::<compend::Result<Vec<_>>>()?)
}

/// Plays `spec` with the set's model in `model_dir` (see the module documentation).
pub fn play_set(args: &SetPlay, model_dir: &Path, spec: &SourceSpec) -> Result<()> {
    let model = SetModel::load(model_dir)?;
    if !args.to.is_empty() && args.to.len() != model.models.len() {
        return Err(compend::Error::Input(format!(
            "--to given {} time(s) for a set of {} projectors: one output per projector, in the \
             set's order",
            args.to.len(),
            model.models.len()
        ))
        .into());
    }
    let record = model.meta.calibration.as_ref().ok_or_else(|| {
        compend::Error::Input(format!(
            "{}: no calibration record in set.json (where the set's picture goes, in which \
             range): calibrate the set with `compend calibrate --rig virtual:SET`",
            model_dir.display()
        ))
    })?;
    if let (Some(rig), Some(m)) = (args.rig, args.monitor) {
        return Err(compend::Error::Input(format!(
            "--monitor {m} and --rig {rig}: the virtual rig has its own outputs; leave one out"
        ))
        .into());
    }
    let Some(rig_text) = args.rig else {
        if args.no_window {
            return play_headless(args, &model, record, spec);
        }
        return play_on_windows(args, model_dir, &model, record, spec);
    };
    let scene_name = match parse_rig(rig_text)? {
        Some(s) => s,
        None => record
            .rig
            .strip_prefix("virtual:")
            .map(str::to_string)
            .ok_or_else(|| {
                compend::Error::Input(format!(
                    "{}: calibrated on {:?}, not the virtual rig: name a scene (--rig \
                     virtual:SCENE)",
                    model_dir.display(),
                    record.rig
                ))
            })?,
    };
    let seed = args
        .seed
        .or_else(|| model.models[0].meta.calibration.as_ref()?.seed)
        .unwrap_or(0);
    let first = &model.models[0];
    let projector = first
        .meta
        .canvas
        .map(|c| compend::raster::ImageSize::new(c.width, c.height))
        .unwrap_or(first.network_size());
    let scene = scene::load(&scene_name)?.with_resolution(model.meta.camera_size, projector);
    let rig = VirtualRig::new(&scene, seed)?;
    if rig.outputs() != model.models.len() {
        return Err(compend::Error::Input(format!(
            "--rig {rig_text}: scene {scene_name:?} has {} projector(s), the model {}",
            rig.outputs(),
            model.models.len()
        ))
        .into());
    }
    let mut camera = rig.clone();
    if let Some(e) = &record.exposure {
        camera.set_exposure(e.chosen)?;
    }
    let mut outputs = (0..rig.outputs())
        .map(|k| rig.output(k))
        .collect::<compend::Result<Vec<_>>>()?;
    let joint = model.joint()?;
    let ctx = compend::gpu::GpuContext::new().context("opening the GPU for the joint pass")?;
    let pass = compend::gpu::joint::JointPass::new(&ctx, &joint)?;
    let out = args.out;
    if let Some(dir) = out {
        check_out(dir)?;
        mark_out(dir)?;
    }
    let mut src = source::open(spec)?;
    src.set_live(false);
    src.prepare()?;
    eprintln!(
        "play: {} on the set of {} projectors of scene {scene_name:?} (seed {seed}), the joint \
         pass on {}",
        src.describe(),
        outputs.len(),
        ctx.describe()
    );
    let delay = scene.latency.delay_frames as u64;
    let range = record.display_range;
    let camera_size = model.meta.camera_size;
    let mut media = start_outputs(
        &args.to,
        outputs.len(),
        outputs[0].size(),
        args.output_fps,
        false,
    )?;
    let mut shown = 0u64;
    loop {
        if args.frames.is_some_and(|n| shown >= n) {
            break;
        }
        let frame = match src.next()? {
            Next::Frame { frame, .. } => frame,
            Next::Idle => {
                std::thread::sleep(std::time::Duration::from_millis(5));
                continue;
            }
            Next::End => break,
        };
        let img: compend::raster::Rgb<compend::raster::Unspecified> = frame.to_image();
        let desired = compend::fov::place_in_area(&range.apply(&img), record.area, camera_size)?;
        pass.run(&ctx, &desired)?;
        let frames = canvases(&pass, &ctx, outputs[0].size())?;
        for (o, f) in outputs.iter_mut().zip(&frames) {
            o.show(f)?;
        }
        if let Some(m) = &mut media {
            m.push(&frames)?;
        }
        // The camera sees the shows `delay` exposures later.
        let mut seen: Option<CamImage> = None;
        for _ in 0..=delay {
            seen = Some(camera.grab()?.image);
        }
        if let (Some(dir), Some(view)) = (out, &seen) {
            compend::pngio::write_rgb(&dir.join(format!("cam_{:06}.png", shown + 1)), view)?;
        }
        shown += 1;
    }
    let written = media.map(SetOutputs::finish).transpose()?;
    if let Some(dir) = out {
        let counts = serde_json::json!({ "shown": shown, "projectors": outputs.len() });
        compend::files::write_atomically(
            &dir.join("play.json"),
            serde_json::to_string_pretty(&counts)?.as_bytes(),
        )?;
    }
    if args.json {
        println!(
            "{}",
            serde_json::json!({ "shown": shown, "projectors": outputs.len(), "written": written })
        );
    }
    eprintln!("play: {shown} frames shown on {} projectors", outputs.len());
    Ok(())
}

/// Plays `spec` on one window per projector's monitor (`--monitor A,B`), in real time, until
/// the source ends (a film), `--frames` refreshes, or a window is closed (Escape).
fn play_on_windows(
    args: &SetPlay,
    model_dir: &Path,
    model: &SetModel,
    record: &SetRecord,
    spec: &SourceSpec,
) -> Result<()> {
    let n = model.models.len();
    let Some(monitors) = args.monitor else {
        return Err(compend::Error::Input(format!(
            "{}: a set of {n} projectors plays on one window per projector's monitor: name them \
             in the set's order with --monitor A,B (names or indices; or play on the virtual \
             rig with --rig virtual)",
            model_dir.display()
        ))
        .into());
    };
    let names: Vec<&str> = monitors.split(',').map(str::trim).collect();
    if names.len() != n || names.iter().any(|m| m.is_empty()) {
        return Err(compend::Error::Input(format!(
            "--monitor {monitors}: {} monitor(s) for a set of {n} projectors (one per \
             projector, in the set's order, comma-separated)",
            names.iter().filter(|m| !m.is_empty()).count()
        ))
        .into());
    }
    if args.out.is_some() {
        return Err(compend::Error::Input(
            "--out holds the virtual camera's views: add --rig virtual, or leave --out out".into(),
        )
        .into());
    }
    let joint = model.joint()?;
    let calibrated = super::model_projector(&model.models[0], None).ok();
    let mut windows = compend::window::ProjectorWindows::open(&names)?;
    // Each projector's image covers its whole frame: a monitor of another size would stretch
    // it to another shape than the one calibrated.
    if let Some(p) = calibrated
        && let Some((m, s)) = windows
            .monitors()
            .into_iter()
            .zip(windows.sizes())
            .find(|(_, s)| s.width * p.height != s.height * p.width)
    {
        return Err(compend::Error::Input(format!(
            "--monitor {m}: the monitor is {s}, the set was calibrated for projectors of {p} \
             (another shape): set the monitors to {p} or calibrate the set on them"
        ))
        .into());
    }
    let pass = compend::gpu::joint::JointPass::new(windows.context(), &joint)?;
    let mut src = source::open(spec)?;
    src.set_live(true);
    src.prepare()?;
    eprintln!(
        "play: {} on {n} windows (monitors {}) at {:.2} Hz, the joint pass on {}",
        src.describe(),
        windows.monitors().join(", "),
        windows.refresh_hz(),
        windows.context().describe()
    );
    let range = record.display_range;
    let camera_size = model.meta.camera_size;
    let size = windows.sizes()[0];
    let mut media = start_outputs(&args.to, n, size, windows.refresh_hz(), true)?;
    let (mut shown, mut refreshes, mut ended) = (0u64, 0u64, false);
    let mut held: Option<Vec<PrjImage>> = None;
    loop {
        if args.frames.is_some_and(|f| refreshes >= f) || !windows.pump() {
            break;
        }
        if !ended {
            match src.next()? {
                Next::Frame { frame, .. } => {
                    let img: compend::raster::Rgb<compend::raster::Unspecified> = frame.to_image();
                    let desired =
                        compend::fov::place_in_area(&range.apply(&img), record.area, camera_size)?;
                    pass.run(windows.context(), &desired)?;
                    shown += 1;
                    // The outputs' canvases, read back once per source frame (a still is
                    // pushed every refresh from here).
                    if media.is_some() {
                        held = Some(canvases(&pass, windows.context(), size)?);
                    }
                }
                Next::Idle => {}
                Next::End => {
                    ended = true;
                    if src.ends_playback() {
                        break;
                    }
                }
            }
        }
        if shown == 0 {
            // Nothing to show yet (a stream still starting).
            std::thread::sleep(std::time::Duration::from_millis(5));
            continue;
        }
        windows.present(&pass.outputs())?;
        if let (Some(m), Some(frames)) = (&mut media, &held) {
            m.push(frames)?;
        }
        refreshes += 1;
        if refreshes == 1 {
            eprintln!("play: first frame presented on every output");
        }
    }
    let written = media.map(SetOutputs::finish).transpose()?;
    let p = windows.presents();
    if args.json {
        println!(
            "{}",
            serde_json::json!({
                "shown": shown,
                "refreshes": refreshes,
                "projectors": n,
                "monitors": windows.monitors(),
                "refresh_hz": windows.refresh_hz(),
                "presented": p.presented,
                "together": p.together,
                "out_of_step": p.out_of_step,
                "skew_ms_max": p.skew_ms_max,
                "written": written,
            })
        );
    }
    eprintln!(
        "play: {shown} source frames in {refreshes} refreshes on {n} outputs ({} together, {} \
         with an output a frame behind)",
        p.together, p.out_of_step
    );
    Ok(())
}

/// Plays `spec` with no display, only to the outputs (`--no-window`): every source frame once,
/// as fast as the joint pass goes, at the projectors' size (`--projector`, else the one the
/// first projector's model was calibrated for).
fn play_headless(
    args: &SetPlay,
    model: &SetModel,
    record: &SetRecord,
    spec: &SourceSpec,
) -> Result<()> {
    let n = model.models.len();
    if args.to.is_empty() {
        return Err(compend::Error::Input(
            "--no-window: give one --to per projector (where the frames go)".into(),
        )
        .into());
    }
    if args.out.is_some() {
        return Err(compend::Error::Input(
            "--out holds the virtual camera's views: add --rig virtual, or leave --out out".into(),
        )
        .into());
    }
    let size = super::model_projector(&model.models[0], args.projector)?;
    let mut src = source::open(spec)?;
    src.set_live(false);
    src.prepare()?;
    let joint = model.joint()?;
    let ctx = compend::gpu::GpuContext::new().context("opening the GPU for the joint pass")?;
    let pass = compend::gpu::joint::JointPass::new(&ctx, &joint)?;
    let mut media = start_outputs(&args.to, n, size, args.output_fps, false)?
        .ok_or_else(|| compend::Error::Input("--no-window needs --to".into()))?;
    eprintln!(
        "play: {} to the outputs only, {n} projector canvases of {size} ({})",
        src.describe(),
        ctx.describe()
    );
    let range = record.display_range;
    let camera_size = model.meta.camera_size;
    let mut shown = 0u64;
    loop {
        if args.frames.is_some_and(|f| shown >= f) {
            break;
        }
        let frame = match src.next()? {
            Next::Frame { frame, .. } => frame,
            Next::Idle => {
                std::thread::sleep(Duration::from_millis(5));
                continue;
            }
            Next::End => break,
        };
        let img: compend::raster::Rgb<compend::raster::Unspecified> = frame.to_image();
        let desired = compend::fov::place_in_area(&range.apply(&img), record.area, camera_size)?;
        pass.run(&ctx, &desired)?;
        media.push(&canvases(&pass, &ctx, size)?)?;
        shown += 1;
    }
    let written = media.finish()?;
    if args.json {
        println!(
            "{}",
            serde_json::json!({ "shown": shown, "projectors": n, "written": written })
        );
    }
    eprintln!("play: {shown} frames to {n} outputs");
    Ok(())
}
