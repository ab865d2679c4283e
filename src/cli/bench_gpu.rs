//! `compend bench-gpu`: per-frame GPU time of the compensation pass at projector resolutions for
//! the `linear` model (or a trained `linear` or residual model) and the simplified CompenNet
//! backbone (synthetic models with seeded weights), each next to a plain texture copy of the
//! same size measured in the same run, and frames dropped at the display rate (`linear`): on
//! the virtual rig, which reads every frame back to the CPU, and with the pipeline alone
//! (upload + pass, no read-back, no display).
//! Writes bench-gpu.json and bench-gpu.md.

use std::path::PathBuf;
use std::time::Duration;

use anyhow::Result;
use compend::fov::DisplayRange;
use compend::gpu::ConvKernels;
use compend::gpu::bench::{Timing, time_compennet_layers, time_copy, time_pass, time_stages};
use compend::gpu::synthetic::{synthetic_compennet_model, synthetic_linear_model};
use compend::gpu::{CompensationPass, GpuContext};
use compend::model::Model;
use compend::playback::ContentFrame;
use compend::player::{Headless, PlayStats, Player, WatchedSink};
use compend::raster::ImageSize;
use compend::rig::{Phase, Simulator, VirtualRig, scene};
use compend::source::{FeedMode, Pattern, SourceSpec};
use serde::Serialize;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// Folder for bench-gpu.json and bench-gpu.md.
    #[arg(long)]
    pub out: PathBuf,
    /// Projector resolutions.
    #[arg(long, value_delimiter = ',', value_parser = super::sim::parse_size,
          default_value = "640x480,800x600,1920x1080,3840x2160")]
    pub sizes: Vec<ImageSize>,
    /// Timed frames per measurement (after --warmup untimed ones); medians are reported.
    #[arg(long, default_value_t = 30)]
    pub iters: usize,
    /// Camera resolution of the model.
    #[arg(long, value_parser = super::sim::parse_size, default_value = "640x480")]
    pub camera: ImageSize,
    /// Network resolution of the models (sides divisible by 4 for CompenNet).
    #[arg(long, value_parser = super::sim::parse_size, default_value = "256x256")]
    pub network: ImageSize,
    /// Timed frames per CompenNet measurement (after --warmup untimed ones; 0 = skip CompenNet): its
    /// backbone is ~3.2 GMAC per 256² frame, slow on software drivers.
    #[arg(long, default_value_t = 10)]
    pub compennet_iters: usize,
    /// Content frame resolution.
    #[arg(long, value_parser = super::sim::parse_size, default_value = "1280x720")]
    pub content: ImageSize,
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
    /// The `linear` model's coefficient lattice: `projector` (what training gives at each
    /// projector size: its resolution, capped at 1920×1080 pixels), `network`, or WxH.
    #[arg(long, value_parser = parse_lattice, default_value = "projector")]
    pub lattice: Lattice,
    /// Time this trained model in place of the synthetic `linear` one: a `linear` or `linear-sl`
    /// model (its own lattice and camera size), or a residual rung's (`compennet++-res`,
    /// `compennet++-res-full`: its `linear` part, correction and sum, on its `linear` part's
    /// lattice), in the `linear` columns.
    #[arg(long, conflicts_with_all = ["lattice", "camera"])]
    pub model: Option<PathBuf>,
    /// The content frame of the timed passes: bars (saturated colours, much of it out of the
    /// projector's reach), ramp, checker or gray (mid gray, all of it in reach).
    #[arg(long, value_parser = parse_pattern, default_value = "bars")]
    pub pattern: Pattern,
    /// Untimed frames before each timed measurement. A GPU that idles at low clocks needs some
    /// hundreds of them to reach its working clock.
    #[arg(long, default_value_t = 5)]
    pub warmup: usize,
    /// How CompenNet's wide layers run (the CompenNet columns and a trained residual
    /// model's correction): `direct`, `tiled`, or `measured` (each wide layer timed with both
    /// when the pass is built, the faster kept). Default: what playback uses on this adapter
    /// (direct on a CPU driver, measured on a GPU).
    #[arg(long, value_enum)]
    pub conv_kernels: Option<ConvKernels>,
    /// Also time the joint pass of a set of two projectors side by side (a third of each
    /// picture overlapping), each at the projector size on the `linear` lattice, for one
    /// desired view of saturated bars (much of the overlap through the bounded least squares).
    #[arg(long)]
    pub joint: bool,
}

fn parse_pattern(s: &str) -> std::result::Result<Pattern, String> {
    match s {
        "bars" => Ok(Pattern::Bars),
        "ramp" => Ok(Pattern::Ramp),
        "checker" => Ok(Pattern::Checker),
        "gray" => Ok(Pattern::Gray),
        _ => Err(format!(
            "pattern `{s}`: expected bars, ramp, checker or gray"
        )),
    }
}

/// The lattice of the synthetic `linear` model.
#[derive(Clone, Copy, Debug)]
pub enum Lattice {
    /// The default lattice training gives for each projector size.
    Projector,
    /// The network size.
    Network,
    /// One size at every projector size.
    Fixed(ImageSize),
}

fn parse_lattice(s: &str) -> std::result::Result<Lattice, String> {
    match s {
        "projector" => Ok(Lattice::Projector),
        "network" => Ok(Lattice::Network),
        _ => super::sim::parse_size(s)
            .map(Lattice::Fixed)
            .map_err(|e| format!("{e} (or `projector`, `network`)")),
    }
}

impl Lattice {
    /// The lattice for a projector of `prj` pixels and a network of `net`.
    fn at(self, prj: ImageSize, net: ImageSize) -> ImageSize {
        match self {
            Self::Projector => compend::fit::default_lattice(net, Some(prj)),
            Self::Network => net,
            Self::Fixed(s) => s,
        }
    }
}

#[derive(Serialize)]
struct Row {
    #[serde(with = "compend::raster::as_pair")]
    projector: ImageSize,
    /// The `linear` model's coefficient lattice.
    #[serde(with = "compend::raster::as_pair")]
    lattice: ImageSize,
    copy: Timing,
    linear: Timing,
    /// Each stage of the `linear` pass alone: place (camera pixels), photometric (lattice
    /// pixels), canvas (projector pixels).
    linear_stages: Vec<StageTiming>,
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
    /// The joint pass of two projectors of this size (`--joint`), both outputs in one
    /// submission, and over the copy of one projector frame.
    joint: Option<Timing>,
    joint_over_copy: Option<f64>,
}

#[derive(Serialize)]
struct StageTiming {
    stage: &'static str,
    #[serde(flatten)]
    timing: Timing,
}

/// What is measured at every projector size.
struct Bench<'a> {
    ctx: &'a GpuContext,
    args: &'a Args,
    /// The trained `linear` model of `--model`.
    trained: Option<Model>,
    /// The synthetic CompenNet++ model, when measured.
    compennet: Option<Model>,
    /// The content frame of the timed passes.
    content: ContentFrame,
}

pub fn run(args: Args) -> Result<()> {
    compend::files::check_out_folder(&args.out)?;
    let trained = match &args.model {
        Some(dir) => {
            let model = Model::load(dir)?;
            if matches!(model.kind, compend::model::Kind::CompenNet { .. }) {
                return Err(compend::error::Error::Input(format!(
                    "--model {}: a {} model; bench-gpu times trained `linear`, `linear-sl` and \
                     residual-rung models (the CompenNet columns time a synthetic backbone)",
                    dir.display(),
                    model.meta.method
                ))
                .into());
            }
            Some(model)
        }
        None => None,
    };
    let ctx = GpuContext::new()?;
    let ctx = match args.conv_kernels {
        Some(k) => ctx.with_conv_kernels(k),
        None => ctx,
    };
    let cam = trained.as_ref().map_or(args.camera, Model::camera_size);
    let net = args.network;
    let compennet = if args.compennet_iters > 0 {
        Some(synthetic_compennet_model(
            cam,
            net,
            compend::nn::compennetpp::Variant::NoRefine,
            0,
        )?)
    } else {
        None
    };
    let bench = Bench {
        ctx: &ctx,
        args: &args,
        trained,
        compennet,
        content: compend::source::pattern::render(args.pattern, args.content, 0)?,
    };
    eprintln!(
        "bench-gpu: {} (camera ({}, {}), network ({}, {}), content ({}, {}), {} convolutions)",
        ctx.describe(),
        cam.width,
        cam.height,
        net.width,
        net.height,
        bench.content.size().width,
        bench.content.size().height,
        ctx.conv.name()
    );
    let rows = args
        .sizes
        .iter()
        .map(|&s| bench.row(s))
        .collect::<Result<Vec<Row>>>()?;
    // A software adapter (lavapipe) reports timestamps, but its copies cost next to nothing on
    // them while the wall clock shows the real memcpy: its ratios are read from the wall clock.
    let software = ctx.adapter.get_info().device_type == wgpu::DeviceType::Cpu;
    let timing = if rows.iter().all(|r| r.copy.gpu_ms.is_some()) {
        "GPU timestamps"
    } else {
        "wall clock, submit to idle"
    };
    let json = serde_json::json!({
        "adapter": ctx.describe(),
        "software_adapter": software,
        "timing": timing,
        "iters": args.iters,
        "warmup": args.warmup,
        "pattern": format!("{:?}", args.pattern).to_lowercase(),
        // The rows hold each size's lattice; this is how they were chosen.
        "lattice": match (&args.model, args.lattice) {
            (Some(_), _) => "the model's".to_string(),
            (None, Lattice::Projector) => "projector".to_string(),
            (None, Lattice::Network) => "network".to_string(),
            (None, Lattice::Fixed(size)) => size.to_string(),
        },
        "model": args.model,
        // The rung timed in the `linear` columns.
        "model_method": bench.trained.as_ref().map_or("linear", |m| m.meta.method.name()),
        "camera": [cam.width, cam.height],
        "network": [net.width, net.height],
        "compennet_iters": args.compennet_iters,
        "conv_kernels": ctx.conv,
        "content": [bench.content.size().width, bench.content.size().height],
        "fps": args.fps,
        "rows": rows,
    });
    compend::files::write_atomically(
        &args.out.join("bench-gpu.json"),
        (serde_json::to_string_pretty(&json)? + "\n").as_bytes(),
    )?;
    let md = bench.markdown(&rows, timing, software);
    compend::files::write_atomically(&args.out.join("bench-gpu.md"), md.as_bytes())?;
    print!("{md}");
    Ok(())
}

impl Bench<'_> {
    /// The measurements at projector size `prj` (pixels).
    fn row(&self, prj: ImageSize) -> Result<Row> {
        let (ctx, args) = (self.ctx, self.args);
        let synthetic;
        let model = match &self.trained {
            Some(m) => m,
            None => {
                synthetic =
                    synthetic_linear_model(args.camera, args.lattice.at(prj, args.network), 0);
                &synthetic
            }
        };
        let lattice = model.network_size();
        let mut pass = CompensationPass::for_display(ctx, model, prj, DisplayRange::FULL)?;
        let copy = time_copy(ctx, prj, args.warmup, args.iters)?;
        let linear = time_pass(ctx, &mut pass, &self.content, args.warmup, args.iters)?;
        let ratio = linear.best_ms() / copy.best_ms();
        let stages = time_stages(ctx, &mut pass, &self.content, args.warmup, args.iters)?;
        eprintln!(
            "bench-gpu: {prj}: copy {:.3} ms, linear ({lattice} lattice) {:.3} ms ({ratio:.2}x; {})",
            copy.best_ms(),
            linear.best_ms(),
            stages
                .iter()
                .map(|(name, t)| format!("{name} {:.3}", t.best_ms()))
                .collect::<Vec<_>>()
                .join(", ")
        );
        let linear_stages = stages
            .into_iter()
            .map(|(stage, timing)| StageTiming { stage, timing })
            .collect();
        let cnn = match &self.compennet {
            Some(m) => Some(self.compennet(m, prj, &copy)?),
            None => None,
        };
        let joint = match args.joint {
            true => Some(self.joint(prj)?),
            false => None,
        };
        let (virtual_rig, headless) = if args.seconds > 0.0 {
            let headless = self.headless_run(model, prj)?;
            (Some(self.virtual_run(model, prj)?), Some(headless))
        } else {
            (None, None)
        };
        Ok(Row {
            projector: prj,
            lattice,
            copy,
            linear,
            linear_stages,
            linear_over_copy: ratio,
            linear_over_copy_wall: linear.wall_ms / copy.wall_ms,
            compennet: cnn,
            compennet_over_copy: cnn.map(|t| t.best_ms() / copy.best_ms()),
            compennet_over_copy_wall: cnn.map(|t| t.wall_ms / copy.wall_ms),
            virtual_rig,
            headless,
            joint,
            joint_over_copy: joint.map(|t| t.best_ms() / copy.best_ms()),
        })
    }

    /// The joint pass of two projectors of `prj` pixels (each on the `linear` lattice).
    fn joint(&self, prj: ImageSize) -> Result<Timing> {
        let (ctx, args) = (self.ctx, self.args);
        let lattice = args.lattice.at(prj, args.network);
        let set = compend::gpu::synthetic::synthetic_joint_model(args.camera, lattice, 0)?;
        let pass = compend::gpu::joint::JointPass::new(ctx, &set)?;
        let bars = [
            [1.0, 1.0, 1.0],
            [1.0, 1.0, 0.0],
            [0.0, 1.0, 1.0],
            [0.0, 1.0, 0.0],
            [1.0, 0.0, 1.0],
            [1.0, 0.0, 0.0],
            [0.0, 0.0, 1.0],
            [0.05, 0.05, 0.05],
        ];
        let w = args.camera.width;
        let desired = compend::raster::CamImage::from_fn(w, args.camera.height, |x, _| {
            bars[(x * bars.len() / w.max(1)).min(bars.len() - 1)]
        });
        pass.upload(ctx, &desired)?;
        let t = compend::gpu::bench::time_work(ctx, args.warmup, args.iters, |enc| {
            pass.encode(enc, None);
            Ok(())
        })?;
        eprintln!(
            "bench-gpu: {prj}: joint pass of two projectors ({lattice} lattices) {:.3} ms",
            t.best_ms()
        );
        Ok(t)
    }

    /// The CompenNet pass at `prj` (and its layers alone with `--layers`).
    fn compennet(&self, model: &Model, prj: ImageSize, copy: &Timing) -> Result<Timing> {
        let (ctx, args) = (self.ctx, self.args);
        let mut pass = CompensationPass::for_display(ctx, model, prj, DisplayRange::FULL)?;
        let t = time_pass(
            ctx,
            &mut pass,
            &self.content,
            args.warmup,
            args.compennet_iters,
        )?;
        if args.layers
            && let compend::gpu::Photometric::CompenNet(stage) = pass.photometric()
        {
            for (name, entry) in stage.layer_kernels() {
                let timed = stage
                    .kernel_timings()
                    .into_iter()
                    .find(|(n, _)| *n == name)
                    .map(|(_, t)| {
                        let t: Vec<String> =
                            t.iter().map(|(e, ms)| format!("{e} {ms:.3} ms")).collect();
                        format!(
                            " (timed alone when a pass first had this shape: {})",
                            t.join(", ")
                        )
                    })
                    .unwrap_or_default();
                eprintln!("bench-gpu:   layer {name} runs {entry}{timed}");
            }
        }
        if args.layers {
            let layers =
                time_compennet_layers(ctx, &mut pass, &self.content, 1, args.compennet_iters)?;
            if ctx.adapter.get_info().device_type == wgpu::DeviceType::Cpu {
                eprintln!(
                    "bench-gpu:   (a software adapter: its timestamps do not show the work; \
                     read the wall times)"
                );
            }
            for (name, t) in layers {
                eprintln!(
                    "bench-gpu:   layer {name}: {:.3} ms ({:.3} ms wall)",
                    t.best_ms(),
                    t.wall_ms
                );
            }
        }
        eprintln!(
            "bench-gpu: {prj}: CompenNet {:.3} ms ({:.2}x the copy)",
            t.best_ms(),
            t.best_ms() / copy.best_ms()
        );
        Ok(t)
    }

    /// A player of the moving test pattern at the display rate, newest frame first (as live),
    /// for the `linear` model on a display of `prj` pixels.
    fn paced_player(&self, linear: &Model, prj: ImageSize) -> Result<Player> {
        let args = self.args;
        let spec = SourceSpec::Pattern {
            pattern: Pattern::Moving,
            size: args.content,
            fps: args.fps,
            frames: None,
        };
        let player = Player::start(
            self.ctx,
            linear,
            prj,
            DisplayRange::FULL,
            compend::source::open(&spec)?,
            FeedMode::Latest,
        )?;
        // Let the source start before the clock does.
        std::thread::sleep(Duration::from_millis(50));
        Ok(player)
    }

    /// Refreshes played per measurement.
    fn refreshes(&self) -> Option<u64> {
        Some((self.args.seconds * self.args.fps).round() as u64)
    }

    /// Plays the paced test pattern at the display rate on the virtual rig and returns the
    /// counts.
    fn virtual_run(&self, linear: &Model, prj: ImageSize) -> Result<PlayStats> {
        let args = self.args;
        let scene = scene::builtin("textured-plane")?.with_resolution(linear.camera_size(), prj);
        let rig = VirtualRig::from_simulator(Simulator::new(&scene, 0, Phase::Calibration)?);
        rig.set_latency(scene::Latency {
            fps: args.fps,
            delay_frames: 0,
            drop_rate: 0.0,
        })?;
        let mut screen = WatchedSink::new(
            self.ctx,
            args.fps,
            rig.clone(),
            rig,
            Box::new(|_, _, _| Ok(())),
        );
        Ok(self
            .paced_player(linear, prj)?
            .run(&mut screen, self.refreshes())?)
    }

    /// Plays the paced test pattern with no read-back and no display and returns the counts.
    fn headless_run(&self, linear: &Model, prj: ImageSize) -> Result<PlayStats> {
        let mut screen = Headless::new(self.ctx, self.args.fps);
        Ok(self
            .paced_player(linear, prj)?
            .run(&mut screen, self.refreshes())?)
    }

    /// bench-gpu.md.
    fn markdown(&self, rows: &[Row], timing: &str, software: bool) -> String {
        let (ctx, args) = (self.ctx, self.args);
        let linear = match (&args.model, &self.trained) {
            (Some(dir), Some(m)) if !m.meta.method.is_linear() => format!(
                "linear: the trained {} model {} (camera {}; the `linear` columns time its whole \
                 pass: its `linear` part, its correction and their sum)",
                m.meta.method,
                dir.display(),
                m.camera_size()
            ),
            (Some(dir), Some(m)) => format!(
                "linear: the trained model {} (camera {})",
                dir.display(),
                m.camera_size()
            ),
            _ => format!("linear: synthetic, seeded (camera {})", args.camera),
        };
        let mut md = format!(
            "# compend bench-gpu\n\nAdapter: {}. Timing: {timing}, median of {} frames ({} for CompenNet) after \
             {} untimed. Models: {linear}, its coefficient lattice in the second column; the simplified CompenNet \
             backbone (synthetic, seeded), camera {}, network {}, {} convolutions; content {} ({:?}). Times in ms as GPU timestamps / wall clock (submit to \
             idle) where the adapter has timestamps, else wall clock.\n\n| projector | linear lattice | copy | linear | linear stages alone: place / photometric / canvas | linear / copy | \
             within 3x | CompenNet | CompenNet / copy | virtual rig @ {} Hz: shown / dropped (source) / dropped (pipeline) | pipeline mean (ms) \
             | pipeline alone: shown / dropped (pipeline) / mean / max (ms) |\n|---|---|---|---|---|---|---|---|---|---|---|---|\n",
            ctx.describe(),
            args.iters,
            args.compennet_iters,
            args.warmup,
            args.camera,
            args.network,
            ctx.conv.name(),
            self.content.size(),
            args.pattern,
            args.fps
        );
        for r in rows {
            md += &markdown_row(r);
        }
        md += "\nThe copy is a texture-to-texture copy of one projector frame (rgba8): the memory-bandwidth \
               floor of any pass that writes one. Virtual-rig playback includes reading each frame back to the \
               CPU for the simulated projector (the window presents from the GPU without it). \
               \"Pipeline alone\" plays the same paced source with neither read-back nor display: each \
               refresh uploads the newest frame, runs the pass and waits for the GPU, which is the \
               window's work per frame without the presentation.\n";
        let joints: Vec<String> = rows
            .iter()
            .filter_map(|r| {
                Some(format!(
                    "- {}: {} ms for both outputs, {:.2}× one frame's copy; half a refresh at {} Hz \
                     is {:.2} ms",
                    r.projector,
                    both(r.joint.as_ref()?),
                    r.joint_over_copy?,
                    args.fps,
                    500.0 / args.fps
                ))
            })
            .collect();
        if !joints.is_empty() {
            md += "\nThe joint pass of a set of two projectors side by side, each at the projector size on \
                   the `linear` lattice, for a view of saturated bars (`--joint`):\n\n";
            md += &joints.join("\n");
            md += "\n";
        }
        if software {
            md += "\nThis adapter renders in software: its GPU timestamps for the copy are not \
                   meaningful, so read the ratios after the slash (wall clock). They say nothing about \
                   a hardware GPU.\n";
        }
        md
    }
}

/// One row of the bench-gpu.md table.
fn markdown_row(r: &Row) -> String {
    let v = r.virtual_rig.as_ref();
    format!(
        "| {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} |\n",
        r.projector,
        r.lattice,
        both(&r.copy),
        both(&r.linear),
        r.linear_stages
            .iter()
            .map(|s| format!("{:.3}", s.timing.best_ms()))
            .collect::<Vec<_>>()
            .join(" / "),
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
    )
}

fn both(t: &Timing) -> String {
    match t.gpu_ms {
        Some(g) => format!("{g:.3} / {:.3}", t.wall_ms),
        None => format!("{:.3}", t.wall_ms),
    }
}
