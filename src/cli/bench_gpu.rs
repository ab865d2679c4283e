//! `compend bench-gpu`: per-frame GPU time of the compensation pass at projector resolutions for
//! the `linear` model and the simplified CompenNet backbone (synthetic models with seeded
//! weights), each next to a plain texture copy of the same size measured in the same run, and
//! frames dropped at the display rate (`linear`): on the virtual rig, which reads every frame
//! back to the CPU, and with the pipeline alone (upload + pass, no read-back, no display).
//! Writes bench-gpu.json and bench-gpu.md.

use std::path::PathBuf;
use std::time::Duration;

use anyhow::Result;
use compend::fov::DisplayRange;
use compend::gpu::CompensationPass;
use compend::gpu::bench::{
    Timing, synthetic_compennet_model, synthetic_linear_model, time_copy, time_pass,
};
use compend::playback::Placement;
use compend::playback::player::{self, PlayStats, Player, VirtualOptions};
use compend::rig::{Phase, Simulator, VirtualRig, scene};
use compend::source::{Feed, FeedMode, Pattern, SourceSpec};
use serde::Serialize;

use super::patterns::{Size, parse_wxh};

#[derive(clap::Args, Debug)]
pub struct Args {
    /// Folder for bench-gpu.json and bench-gpu.md.
    #[arg(long)]
    pub out: PathBuf,
    /// Projector resolutions.
    #[arg(long, value_delimiter = ',', value_parser = parse_size,
          default_value = "640x480,800x600,1920x1080,3840x2160")]
    pub sizes: Vec<Size>,
    /// Timed frames per measurement (after 5 warm-up frames); medians are reported.
    #[arg(long, default_value_t = 30)]
    pub iters: usize,
    /// Camera resolution of the model.
    #[arg(long, value_parser = parse_size, default_value = "640x480")]
    pub camera: Size,
    /// Network resolution of the models (sides divisible by 4 for CompenNet).
    #[arg(long, value_parser = parse_size, default_value = "256x256")]
    pub network: Size,
    /// Timed frames per CompenNet measurement (after 2 warm-up frames; 0 = skip CompenNet): its
    /// backbone is ~3.2 GMAC per 256² frame, slow on software drivers.
    #[arg(long, default_value_t = 10)]
    pub compennet_iters: usize,
    /// Content frame resolution.
    #[arg(long, value_parser = parse_size, default_value = "1280x720")]
    pub content: Size,
    /// Seconds of playback at the display rate per size, with the pipeline alone and then on the
    /// virtual rig (0 = skip both).
    #[arg(long, default_value_t = 2.0)]
    pub seconds: f64,
    /// Also time each CompenNet layer alone and print the times (stderr).
    #[arg(long)]
    pub layers: bool,
    /// Display rate of the virtual-rig run, Hz (the source runs at the same rate).
    #[arg(long, default_value_t = 60.0)]
    pub fps: f64,
}

fn parse_size(s: &str) -> std::result::Result<Size, String> {
    parse_wxh(s, false)
}

#[derive(Serialize)]
struct Row {
    projector: (usize, usize),
    copy: Timing,
    linear: Timing,
    /// linear / copy, GPU timestamps where available.
    linear_over_copy: f64,
    /// linear / copy, wall clock (submit to idle) for both.
    linear_over_copy_wall: f64,
    /// The simplified CompenNet backbone (CompenNet++ family), when measured.
    compennet: Option<Timing>,
    /// compennet / copy, GPU timestamps where available.
    compennet_over_copy: Option<f64>,
    /// compennet / copy, wall clock for both.
    compennet_over_copy_wall: Option<f64>,
    virtual_rig: Option<PlayStats>,
    /// The same paced playback with no read-back and no display: upload + pass, waited for.
    headless: Option<PlayStats>,
}

pub fn run(args: Args) -> Result<()> {
    let ctx = super::play::gpu()?;
    let (cam, net) = (
        (args.camera.width, args.camera.height),
        (args.network.width, args.network.height),
    );
    let model = synthetic_linear_model(cam, net, 0);
    let compennet = if args.compennet_iters > 0 {
        Some(synthetic_compennet_model(
            cam,
            net,
            compend::nn::train::Variant::NoRefine,
            0,
        )?)
    } else {
        None
    };
    let content = compend::source::pattern::render(
        Pattern::Bars,
        (args.content.width, args.content.height),
        0,
    );
    eprintln!(
        "bench-gpu: {} (camera {cam:?}, network {net:?}, content {:?})",
        ctx.describe(),
        content.size()
    );
    let mut rows = Vec::new();
    for s in &args.sizes {
        let prj = (s.width, s.height);
        let placement = Placement::for_model(&model, prj, DisplayRange::FULL)?;
        let mut pass = CompensationPass::new(&ctx, &model, placement)?;
        let copy = time_copy(&ctx, prj, 5, args.iters)?;
        let linear = time_pass(&ctx, &mut pass, &content, 5, args.iters)?;
        let ratio = linear.best_ms() / copy.best_ms();
        eprintln!(
            "bench-gpu: {}x{}: copy {:.3} ms, linear {:.3} ms ({ratio:.2}x)",
            prj.0,
            prj.1,
            copy.best_ms(),
            linear.best_ms()
        );
        let cnn = match &compennet {
            Some(m) => {
                let placement = Placement::for_model(m, prj, DisplayRange::FULL)?;
                let mut pass = CompensationPass::new(&ctx, m, placement)?;
                let t = time_pass(&ctx, &mut pass, &content, 2, args.compennet_iters)?;
                if args.layers {
                    for (name, t) in compend::gpu::bench::time_compennet_layers(
                        &ctx,
                        &mut pass,
                        &content,
                        1,
                        args.compennet_iters,
                    )? {
                        eprintln!(
                            "bench-gpu:   layer {name}: {:.3} ms ({:.3} ms wall)",
                            t.best_ms(),
                            t.wall_ms
                        );
                    }
                }
                eprintln!(
                    "bench-gpu: {}x{}: CompenNet {:.3} ms ({:.2}x the copy)",
                    prj.0,
                    prj.1,
                    t.best_ms(),
                    t.best_ms() / copy.best_ms()
                );
                Some(t)
            }
            None => None,
        };
        let (virtual_rig, headless) = if args.seconds > 0.0 {
            let placement = Placement::for_model(&model, prj, DisplayRange::FULL)?;
            let alone = CompensationPass::new(&ctx, &model, placement)?;
            let headless = headless_run(&ctx, alone, &args)?;
            (
                Some(virtual_run(&ctx, &model, pass, prj, &args)?),
                Some(headless),
            )
        } else {
            (None, None)
        };
        rows.push(Row {
            projector: prj,
            copy,
            linear,
            linear_over_copy: ratio,
            linear_over_copy_wall: linear.wall_ms / copy.wall_ms,
            compennet: cnn,
            compennet_over_copy: cnn.map(|t| t.best_ms() / copy.best_ms()),
            compennet_over_copy_wall: cnn.map(|t| t.wall_ms / copy.wall_ms),
            virtual_rig,
            headless,
        });
    }
    std::fs::create_dir_all(&args.out)
        .map_err(|e| compend::Error::io(&args.out, "create folder", e))?;
    let timing = if rows.iter().all(|r| r.copy.gpu_ms.is_some()) {
        "GPU timestamps"
    } else {
        "wall clock, submit to idle"
    };
    // A software adapter (lavapipe) reports timestamps, but its copies cost next to nothing on
    // them while the wall clock shows the real memcpy: its ratios are read from the wall clock.
    let software = ctx.adapter.get_info().device_type == wgpu::DeviceType::Cpu;
    let json = serde_json::json!({
        "adapter": ctx.describe(),
        "software_adapter": software,
        "timing": timing,
        "iters": args.iters,
        "camera": cam,
        "network": net,
        "compennet_iters": args.compennet_iters,
        "content": content.size(),
        "fps": args.fps,
        "rows": rows,
    });
    let jp = args.out.join("bench-gpu.json");
    std::fs::write(&jp, serde_json::to_string_pretty(&json)? + "\n")
        .map_err(|e| compend::Error::io(&jp, "write", e))?;
    let mut md = format!(
        "# compend bench-gpu\n\nAdapter: {}. Timing: {timing}, median of {} frames ({} for CompenNet). Models \
         (synthetic, seeded): linear and the simplified CompenNet backbone, camera {}x{}, network {}x{}; \
         content {}x{}. Times in ms as GPU timestamps / wall clock (submit to \
         idle) where the adapter has timestamps, else wall clock.\n\n| projector | copy | linear | linear / copy | \
         within 3x | CompenNet | CompenNet / copy | virtual rig @ {} Hz: shown / dropped (source) / dropped (pipeline) | pipeline mean (ms) \
         | pipeline alone: shown / dropped (pipeline) / mean / max (ms) |\n|---|---|---|---|---|---|---|---|---|---|\n",
        ctx.describe(),
        args.iters,
        args.compennet_iters,
        cam.0,
        cam.1,
        net.0,
        net.1,
        content.width,
        content.height,
        args.fps
    );
    for r in &rows {
        let v = r.virtual_rig.as_ref();
        md += &format!(
            "| {}x{} | {} | {} | {} | {} | {} | {} | {} | {} | {} |\n",
            r.projector.0,
            r.projector.1,
            both(&r.copy),
            both(&r.linear),
            match r.linear.gpu_ms {
                Some(_) => format!("{:.2} / {:.2}", r.linear_over_copy, r.linear_over_copy_wall),
                None => format!("{:.2}", r.linear_over_copy_wall),
            },
            if r.linear_over_copy <= 3.0 {
                "yes"
            } else {
                "no"
            },
            r.compennet.as_ref().map_or("-".into(), both),
            match (
                r.compennet,
                r.compennet_over_copy,
                r.compennet_over_copy_wall
            ) {
                (Some(t), Some(g), Some(w)) if t.gpu_ms.is_some() => format!("{g:.1} / {w:.1}"),
                (Some(_), _, Some(w)) => format!("{w:.1}"),
                _ => "-".into(),
            },
            v.map_or("-".into(), |v| format!(
                "{} / {} / {}",
                v.shown, v.dropped_source, v.dropped_pipeline
            )),
            v.map_or("-".into(), |v| format!("{:.2}", v.pipeline_ms_mean)),
            r.headless.as_ref().map_or("-".into(), |h| format!(
                "{} / {} / {:.2} / {:.2}",
                h.shown, h.dropped_pipeline, h.pipeline_ms_mean, h.pipeline_ms_max
            )),
        );
    }
    md += "\nThe copy is a texture-to-texture copy of one projector frame (rgba8): the memory-bandwidth \
           floor of any pass that writes one. Virtual-rig playback includes reading each frame back to the \
           CPU for the simulated projector (the window presents from the GPU without it). \
           \"Pipeline alone\" plays the same paced source with neither read-back nor display: each \
           refresh uploads the newest frame, runs the pass and waits for the GPU, which is the \
           window's work per frame without the presentation.\n";
    if software {
        md += "\nThis adapter renders in software: its GPU timestamps for the copy are not \
               meaningful, so read the ratios after the slash (wall clock). They say nothing about \
               a hardware GPU.\n";
    }
    let mp = args.out.join("bench-gpu.md");
    std::fs::write(&mp, &md).map_err(|e| compend::Error::io(&mp, "write", e))?;
    print!("{md}");
    Ok(())
}

fn both(t: &Timing) -> String {
    match t.gpu_ms {
        Some(g) => format!("{g:.3} / {:.3}", t.wall_ms),
        None => format!("{:.3}", t.wall_ms),
    }
}

/// Plays a paced test pattern at the display rate on the virtual rig and returns the counts.
fn virtual_run(
    ctx: &compend::gpu::GpuContext,
    model: &compend::model::Model,
    pass: CompensationPass,
    prj: (usize, usize),
    args: &Args,
) -> Result<PlayStats> {
    let scene = scene::builtin("textured-plane")?.with_resolution(model.camera_size(), prj);
    let rig = VirtualRig::from_simulator(Simulator::new(&scene, 0, Phase::Calibration)?);
    rig.set_latency(scene::Latency {
        fps: args.fps,
        delay_frames: 0,
        drop_rate: 0.0,
    })?;
    let mut player = paced_player(pass, args)?;
    let stats = player::play_virtual(
        ctx,
        &mut player,
        &rig,
        VirtualOptions {
            fps: args.fps,
            refreshes: Some((args.seconds * args.fps).round() as u64),
            mode: FeedMode::Latest,
        },
        Box::new(|_, _, _| Ok(())),
    )?;
    Ok(stats)
}

/// A player of the moving test pattern at the display rate, newest frame first (as live).
fn paced_player(pass: CompensationPass, args: &Args) -> Result<Player> {
    let spec = SourceSpec::Pattern {
        pattern: Pattern::Moving,
        size: (args.content.width, args.content.height),
        fps: args.fps,
        frames: None,
    };
    let player = Player::new(
        pass,
        Feed::spawn(compend::source::open(&spec)?, FeedMode::Latest)?,
    );
    // Let the source start before the clock does.
    std::thread::sleep(Duration::from_millis(50));
    Ok(player)
}

/// Plays the paced test pattern with no read-back and no display and returns the counts.
fn headless_run(
    ctx: &compend::gpu::GpuContext,
    pass: CompensationPass,
    args: &Args,
) -> Result<PlayStats> {
    let mut player = paced_player(pass, args)?;
    Ok(player::play_headless(
        ctx,
        &mut player,
        args.fps,
        Some((args.seconds * args.fps).round() as u64),
    )?)
}
