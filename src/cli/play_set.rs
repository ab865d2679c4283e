//! `compend play --model SET --rig virtual[:SCENE]`: a set of projectors' joint model plays a
//! source on the set's virtual rig, every frame through the joint pass on the GPU
//! (`gpu::joint::JointPass`), each projector's image shown on its output, the camera's view of
//! the whole written to `--out` (cam_NNNNNN.png, numbered by source frame). Offline: every
//! source frame is shown once. Sets play on the virtual rig only so far.

use std::path::Path;

use anyhow::{Context, Result};
use compend::device::{DisplaySink, FrameSource};
use compend::model::set::SetModel;
use compend::raster::{CamImage, Rect};
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
    /// `--to` or `--no-window` was given: a projector frame to send, which a set has not.
    pub single_frame_output: bool,
}

/// Plays `spec` with the set's model in `model_dir` (see the module documentation).
pub fn play_set(args: &SetPlay, model_dir: &Path, spec: &SourceSpec) -> Result<()> {
    let model = SetModel::load(model_dir)?;
    let Some(rig_text) = args.rig else {
        return Err(compend::Error::Input(format!(
            "{}: the model of a set of {} projectors plays on the virtual rig only so far: add \
             --rig virtual (one window per projector's monitor is to come)",
            model_dir.display(),
            model.models.len()
        ))
        .into());
    };
    if args.single_frame_output {
        return Err(compend::Error::Input(
            "--to and --no-window: a set of projectors has no single projector frame to send; \
             its camera views go to --out"
                .into(),
        )
        .into());
    }
    let record = model.meta.calibration.as_ref().ok_or_else(|| {
        compend::Error::Input(format!(
            "{}: no calibration record in set.json (where the set's picture goes, in which \
             range): calibrate the set with `compend calibrate --rig virtual:SET`",
            model_dir.display()
        ))
    })?;
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
        for (o, net) in outputs.iter_mut().zip(pass.read(&ctx)?) {
            let size = o.size();
            o.show(&compend::playback::place_on_canvas(
                &net,
                Rect::covering(size),
                size,
            )?)?;
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
            serde_json::json!({ "shown": shown, "projectors": outputs.len() })
        );
    }
    eprintln!("play: {shown} frames shown on {} projectors", outputs.len());
    Ok(())
}
