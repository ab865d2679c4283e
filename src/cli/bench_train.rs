//! `compend bench-train`: what training and inference cost on this machine's CPU, for the
//! CompenNet++ rungs (the full network at the network size, the CPU-sized rung at half of it)
//! and the `linear` rung, each set against the machine's own arithmetic rate measured in the same
//! run (a candle matrix product and a representative convolution). Synthetic data with seeded
//! weights: the figures are costs, not accuracies. Writes bench-train.json and bench-train.md.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result};
use candle_core::{Device, Tensor};
use compend::model::Method;
use compend::nn::compennet::{backbone_macs, surface_macs};
use compend::nn::compennetpp::{GeometryInit, Variant};
use compend::nn::train::{Data, Settings};
use compend::raster::{CamImage, ImageSize, NetImage};
use serde::Serialize;

use super::patterns::parse_wxh;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// Folder for bench-train.json and bench-train.md.
    #[arg(long)]
    pub out: PathBuf,
    /// Training steps timed per CompenNet++ rung (after one untimed step).
    #[arg(long, default_value_t = 3)]
    pub steps: usize,
    /// Batch size of the timed steps.
    #[arg(long, default_value_t = 4)]
    pub batch: usize,
    /// Network side of the full model (a multiple of 8; the CPU rung works at half of it).
    #[arg(long, default_value_t = 256)]
    pub network: usize,
    /// Camera resolution of the synthetic captures.
    #[arg(long, value_parser = parse_camera, default_value = "640x480")]
    pub camera: ImageSize,
    /// Inference frames timed per model (after one untimed frame).
    #[arg(long, default_value_t = 3)]
    pub frames: usize,
    /// Training pairs of the timed `linear` fit (0 = skip it).
    #[arg(long, default_value_t = 48)]
    pub linear_pairs: usize,
    /// A Python interpreter with PyTorch: the same CompenNet++ training steps (same sizes,
    /// batch and thread count) are timed in PyTorch in this run (`scripts/bench_torch.py`,
    /// compiled in and fed on stdin), and the ratio candle / PyTorch is reported per rung.
    #[arg(long, value_name = "PYTHON")]
    pub torch: Option<PathBuf>,
    /// Rounds per CompenNet++ rung: each round times `--steps` steps in candle and then (with
    /// `--torch`) in PyTorch, so a slow spell of the machine falls on both. Each side's figure
    /// is the median step over all its rounds.
    #[arg(long, default_value_t = 1)]
    pub rounds: usize,
    /// The rows to measure, comma-separated: `compennet++`, `compennet++-cpu`, `linear`.
    #[arg(
        long,
        value_delimiter = ',',
        value_parser = parse_row,
        default_value = "compennet++,compennet++-cpu,linear"
    )]
    pub methods: Vec<Method>,
}

/// The rows `bench-train` can measure, in table order.
const METHODS: [Method; 3] = [Method::CompenNetPp, Method::CompenNetPpCpu, Method::Linear];

/// A `--methods` entry: one of [`METHODS`].
fn parse_row(s: &str) -> std::result::Result<Method, String> {
    Method::from_name(s)
        .filter(|m| METHODS.contains(m))
        .ok_or_else(|| {
            format!(
                "unknown row {s:?}; expected some of {}",
                METHODS.map(Method::name).join(", ")
            )
        })
}

/// The PyTorch twin of the training step (run by `--torch`).
const TORCH_SCRIPT: &str = include_str!("../../scripts/bench_torch.py");

/// PyTorch's timed steps (ms per step) for the same model and sizes and its name, or why there
/// are none.
fn torch_train_steps(
    python: &std::path::Path,
    side: usize,
    width: usize,
    camera: ImageSize,
    batch: usize,
    steps: usize,
) -> std::result::Result<(Vec<f64>, String), String> {
    use std::io::Write;
    use std::process::{Command, Stdio};
    let mut child = Command::new(python)
        .args([
            "-",
            "--network",
            &side.to_string(),
            "--width",
            &width.to_string(),
        ])
        .args(["--camera", &camera.to_string()])
        .args(["--batch", &batch.to_string(), "--steps", &steps.to_string()])
        .args(["--threads", &rayon::current_num_threads().to_string()])
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .map_err(|e| format!("{}: could not start ({e})", python.display()))?;
    if let Some(mut stdin) = child.stdin.take() {
        stdin
            .write_all(TORCH_SCRIPT.as_bytes())
            .map_err(|e| format!("{}: writing the script failed ({e})", python.display()))?;
    }
    let out = child
        .wait_with_output()
        .map_err(|e| format!("{}: {e}", python.display()))?;
    if !out.status.success() {
        let err = String::from_utf8_lossy(&out.stderr);
        let last = err.lines().last().unwrap_or("").trim();
        return Err(format!(
            "{} exited with {}: {last}",
            python.display(),
            out.status
        ));
    }
    let v: serde_json::Value = serde_json::from_slice(&out.stdout)
        .map_err(|e| format!("{}: unreadable output ({e})", python.display()))?;
    let steps_ms: Vec<f64> = v["step_ms"]
        .as_array()
        .map(|a| a.iter().filter_map(|x| x.as_f64()).collect())
        .filter(|a: &Vec<f64>| a.len() == steps)
        .ok_or_else(|| {
            format!(
                "{}: expected step_ms with {steps} numbers in {v}",
                python.display()
            )
        })?;
    let name = v["framework"].as_str().unwrap_or("pytorch").to_string();
    Ok((steps_ms, name))
}

/// The candle / PyTorch cell: the ratio of the medians, and with several rounds the range of the
/// per-round ratios.
fn ratio_cell(r: &Row) -> String {
    match (r.candle_over_torch, r.round_ratios.as_slice()) {
        (None, _) => "–".into(),
        (Some(f), [] | [_]) => format!("{f:.2}×"),
        (Some(f), rr) => {
            let lo = rr.iter().copied().fold(f64::INFINITY, f64::min);
            let hi = rr.iter().copied().fold(f64::NEG_INFINITY, f64::max);
            format!("{f:.2}× (rounds {lo:.2}–{hi:.2})")
        }
    }
}

fn parse_camera(s: &str) -> std::result::Result<ImageSize, String> {
    parse_wxh(s, false)
}

/// The machine's arithmetic rate as candle reaches it, GFLOP/s (best of three).
#[derive(Debug, Serialize)]
struct Machine {
    threads: usize,
    /// f32 matrix product 1024³.
    matmul_gflops: f64,
    /// f32 convolution 128→256 channels, 3×3, 64×64, batch 8 (the size of conv4 at 256²).
    conv_gflops: f64,
}

/// One model's costs.
#[derive(Debug, Serialize)]
struct Row {
    method: String,
    /// Network (output) side.
    network: usize,
    /// Base channel width (CompenNet++) or `null` (linear).
    width: Option<usize>,
    /// Milliseconds per training sample (forward, backward and update; CompenNet++: the median
    /// timed step over all rounds / batch), or the whole fit divided by the pairs (linear, a
    /// closed-form fit).
    train_ms_per_sample: Option<f64>,
    /// Arithmetic per training sample, GFLOP (2 per multiply-accumulate: forward ≈ 1/3 of
    /// forward + backward; the surface branch runs once per batch).
    train_gflop_per_sample: Option<f64>,
    /// Achieved training rate, GFLOP/s, and its fraction of the measured matmul rate.
    train_gflops: Option<f64>,
    train_fraction_of_matmul: Option<f64>,
    /// Milliseconds per inference frame on the CPU (the simplified model: camera image in,
    /// network image out).
    frame_ms: f64,
    /// Arithmetic per inference frame, GMAC (the simplified backbone; `null` for linear).
    frame_gmac: Option<f64>,
    /// PyTorch's ms per training sample for the same model in this run (`--torch`), its
    /// version, and candle's time over PyTorch's.
    torch_ms_per_sample: Option<f64>,
    torch: Option<String>,
    candle_over_torch: Option<f64>,
    /// candle / PyTorch per round (`--rounds`), each from that round's median steps.
    round_ratios: Vec<f64>,
    error: Option<String>,
}

fn best_of<F: FnMut() -> Result<()>>(n: usize, mut f: F) -> Result<f64> {
    f()?; // untimed
    let mut best = f64::INFINITY;
    for _ in 0..n {
        let t = Instant::now();
        f()?;
        best = best.min(t.elapsed().as_secs_f64());
    }
    Ok(best)
}

fn machine() -> Result<Machine> {
    let dev = Device::Cpu;
    let n = 1024usize;
    let a = Tensor::rand(0f32, 1.0, (n, n), &dev)?;
    let b = Tensor::rand(0f32, 1.0, (n, n), &dev)?;
    let t = best_of(3, || {
        a.matmul(&b)?;
        Ok(())
    })?;
    let matmul_gflops = 2.0 * (n * n * n) as f64 / t / 1e9;
    let x = Tensor::rand(0f32, 1.0, (8, 128, 64, 64), &dev)?;
    let w = Tensor::rand(-0.1f32, 0.1, (256, 128, 3, 3), &dev)?;
    let t = best_of(3, || {
        x.conv2d(&w, 1, 1, 1, 1)?;
        Ok(())
    })?;
    let conv_gflops = 2.0 * (8u64 * 64 * 64 * 128 * 256 * 9) as f64 / t / 1e9;
    Ok(Machine {
        threads: rayon::current_num_threads(),
        matmul_gflops,
        conv_gflops,
    })
}

/// The median of `v` (not empty).
fn median(v: &[f64]) -> f64 {
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    let n = s.len();
    if n % 2 == 1 {
        s[n / 2]
    } else {
        0.5 * (s[n / 2 - 1] + s[n / 2])
    }
}

/// Milliseconds per training step of `variant` on random data: `steps` timed steps after one.
fn compennet_train_steps(
    variant: Variant,
    side: usize,
    camera: ImageSize,
    batch: usize,
    steps: usize,
) -> compend::Result<Vec<f64>> {
    let ce = |e: candle_core::Error| compend::Error::Failed(format!("synthetic data: {e}"));
    let dev = Device::Cpu;
    let ImageSize {
        width: cw,
        height: ch,
    } = camera;
    let data = Data {
        captures: Tensor::rand(0f32, 1.0, (batch, 3, ch, cw), &dev).map_err(ce)?,
        surface: Tensor::rand(0f32, 1.0, (1, 3, ch, cw), &dev).map_err(ce)?,
        targets: Tensor::rand(0f32, 1.0, (batch, 3, side, side), &dev).map_err(ce)?,
        base: None,
    };
    let mut settings = Settings::new(variant, 0);
    // Costs only: the starting weights do not change them.
    settings.photometric = compend::nn::pretrain::PhotometricInit::Kaiming;
    settings.iters = Some(steps + 1);
    settings.batch = Some(batch);
    let never = std::sync::atomic::AtomicBool::new(false);
    // Time between the end of the first step and the end of the last.
    let mut marks = Vec::new();
    let init = GeometryInit::Affine([[0.8, 0.0, 0.0], [0.0, 0.8, 0.0]]);
    compend::nn::train::train(
        &data,
        init,
        &settings,
        &never,
        |_, _, _| marks.push(Instant::now()),
        |_, _| Ok(true),
    )?;
    if marks.len() < 2 {
        return Err(compend::Error::Failed("no training step was timed".into()));
    }
    Ok(marks
        .windows(2)
        .map(|w| 1e3 * (w[1] - w[0]).as_secs_f64())
        .collect())
}

fn frame_ms(model: &compend::model::Model, camera: ImageSize, frames: usize) -> Result<f64> {
    let ImageSize {
        width: cw,
        height: ch,
    } = camera;
    let img = CamImage::from_fn(cw, ch, |x, y| {
        let v = ((x * 7 + y * 3) % 17) as f32 / 16.0;
        [v, 0.5 * v + 0.25, 1.0 - v]
    });
    model.infer(&img)?; // untimed
    let t = Instant::now();
    for _ in 0..frames.max(1) {
        model.infer(&img)?;
    }
    Ok(1e3 * t.elapsed().as_secs_f64() / frames.max(1) as f64)
}

fn compennet_row(
    a: &Args,
    variant: Variant,
    side: usize,
    camera: ImageSize,
    m: &Machine,
) -> Result<Row> {
    let width = variant.width();
    let macs = backbone_macs(side, side, width) + surface_macs(side, side, width) / a.batch as f64;
    let gflop = 3.0 * 2.0 * macs / 1e9;
    // Per-step times (ms) of every round, candle's and PyTorch's.
    let (mut candle_steps, mut torch_steps) = (Vec::new(), Vec::new());
    let (mut torch, mut errors) = (None, Vec::new());
    let mut round_ratios = Vec::new();
    for round in 1..=a.rounds {
        eprintln!(
            "bench-train: {} at {side}² (width {width}): {} training steps of batch {} (round \
             {round} of {})",
            variant.method(),
            a.steps,
            a.batch,
            a.rounds
        );
        let c = match compennet_train_steps(variant, side, camera, a.batch, a.steps) {
            Ok(v) => v,
            Err(e) => {
                errors.push(e.to_string());
                break;
            }
        };
        if let Some(python) = &a.torch {
            eprintln!(
                "bench-train: the same steps in PyTorch ({})",
                python.display()
            );
            match torch_train_steps(python, side, width, camera, a.batch, a.steps) {
                Ok((t, name)) => {
                    round_ratios.push(median(&c) / median(&t));
                    torch_steps.extend(t);
                    torch = Some(name);
                }
                Err(e) => {
                    errors.push(e);
                    candle_steps.extend(c);
                    break;
                }
            }
        }
        candle_steps.extend(c);
    }
    let per_sample = |v: &Vec<f64>| (!v.is_empty()).then(|| median(v) / a.batch as f64);
    let train_ms = per_sample(&candle_steps);
    let torch_ms = per_sample(&torch_steps);
    let error = (!errors.is_empty()).then(|| errors.join("; "));
    let model = compend::gpu::synthetic::synthetic_compennet_model(
        camera,
        ImageSize::new(side, side),
        variant,
        0,
    )?;
    let frame = frame_ms(&model, camera, a.frames)?;
    let rate = train_ms.map(|ms| gflop / (ms / 1e3));
    Ok(Row {
        method: variant.method().into(),
        network: side,
        width: Some(width),
        train_ms_per_sample: train_ms,
        train_gflop_per_sample: Some(gflop),
        train_gflops: rate,
        train_fraction_of_matmul: rate.map(|r| r / m.matmul_gflops),
        frame_ms: frame,
        frame_gmac: Some(backbone_macs(side, side, width) / 1e9),
        candle_over_torch: train_ms.zip(torch_ms).map(|(c, t)| c / t),
        round_ratios,
        torch_ms_per_sample: torch_ms,
        torch,
        error,
    })
}

/// The `linear` fit on smooth synthetic pairs (its cost barely depends on the content) and the
/// per-frame cost of its simplified form on the default lattice.
fn linear_row(a: &Args, camera: ImageSize) -> Result<Row> {
    let side = a.network;
    let lattice = compend::fit::default_lattice(ImageSize::new(side, side), None);
    let train_ms = if a.linear_pairs > 0 {
        eprintln!(
            "bench-train: linear fit on {} synthetic pairs",
            a.linear_pairs
        );
        let ImageSize {
            width: cw,
            height: ch,
        } = camera;
        let pairs: Vec<(CamImage, NetImage)> = (0..a.linear_pairs)
            .map(|i| {
                let f = 1.0 + i as f32 * 0.37;
                let t = NetImage::from_fn(side, side, |x, y| {
                    let (u, v) = (x as f32 / side as f32, y as f32 / side as f32);
                    [
                        0.5 + 0.4 * (f * 6.0 * u).sin(),
                        0.5 + 0.4 * (f * 5.0 * v).cos(),
                        0.5 + 0.4 * (f * 4.0 * (u + v)).sin(),
                    ]
                });
                let c = CamImage::from_fn(cw, ch, |x, y| {
                    let (sx, sy) = (x * side / cw, y * side / ch);
                    t.get(sx.min(side - 1), sy.min(side - 1))
                        .map(|v| 0.1 + 0.8 * v)
                });
                (c, t)
            })
            .collect();
        let (caps, tgts): (Vec<_>, Vec<_>) = pairs.into_iter().unzip();
        let settings = compend::linear::FitSettings {
            network_size: ImageSize::new(side, side),
            lattice: Some(lattice),
            ..Default::default()
        };
        let init = compend::warp::Warp::from_affine([[0.9, 0.0, 0.0], [0.0, 0.9, 0.0]]);
        let t = Instant::now();
        compend::linear::fit(&caps, &tgts, init, &settings, |_, _, _| {})?;
        Some(1e3 * t.elapsed().as_secs_f64() / a.linear_pairs as f64)
    } else {
        None
    };
    let model = compend::gpu::synthetic::synthetic_linear_model(camera, lattice, 0);
    Ok(Row {
        method: compend::linear::METHOD.into(),
        network: lattice.width,
        width: None,
        train_ms_per_sample: train_ms,
        train_gflop_per_sample: None,
        train_gflops: None,
        train_fraction_of_matmul: None,
        frame_ms: frame_ms(&model, camera, a.frames)?,
        frame_gmac: None,
        torch_ms_per_sample: None,
        torch: None,
        candle_over_torch: None,
        round_ratios: Vec::new(),
        error: None,
    })
}

pub fn run(a: Args) -> Result<()> {
    if a.network < 8 || !a.network.is_multiple_of(8) {
        return Err(compend::Error::Input(format!(
            "--network {}: expected a multiple of 8 (the CPU rung works at half of it, which \
             CompenNet needs divisible by 4)",
            a.network
        ))
        .into());
    }
    if a.steps == 0 || a.batch == 0 || a.rounds == 0 {
        return Err(compend::Error::Input(
            "--steps, --batch and --rounds must be at least 1".into(),
        )
        .into());
    }
    compend::files::check_out_folder(&a.out)?;
    std::fs::create_dir_all(&a.out).with_context(|| format!("creating {}", a.out.display()))?;
    let camera = a.camera;
    eprintln!("bench-train: measuring the machine's arithmetic rate");
    let m = machine()?;
    let mut rows = Vec::new();
    for method in METHODS {
        if !a.methods.contains(&method) {
            continue;
        }
        rows.push(match method {
            Method::CompenNetPp => compennet_row(&a, Variant::Full, a.network, camera, &m)?,
            Method::CompenNetPpCpu => compennet_row(&a, Variant::Cpu, a.network / 2, camera, &m)?,
            _ => linear_row(&a, camera)?,
        });
    }
    let json = serde_json::json!({ "machine": m, "rows": rows, "camera": [camera.width, camera.height],
                                   "steps": a.steps, "batch": a.batch, "rounds": a.rounds });
    let opt = |v: Option<f64>, p: usize| v.map_or("–".to_string(), |x| format!("{x:.p$}"));
    let mut md = format!(
        "# compend bench-train\n\nMachine ({} threads): candle matmul 1024³ {:.1} GFLOP/s, \
         conv 128→256 3×3 at 64² batch 8 {:.1} GFLOP/s (best of three, this run).\n\n\
         | method | network | width | train ms/sample | GFLOP/sample | GFLOP/s | of matmul | PyTorch ms/sample | candle / PyTorch | frame ms | frame GMAC |\n\
         |---|---|---|---|---|---|---|---|---|---|---|\n",
        m.threads, m.matmul_gflops, m.conv_gflops
    );
    for r in &rows {
        md += &format!(
            "| {} | {}² | {} | {} | {} | {} | {} | {} | {} | {:.1} | {} |\n",
            r.method,
            r.network,
            r.width.map_or("–".into(), |w| w.to_string()),
            opt(r.train_ms_per_sample, 1),
            opt(r.train_gflop_per_sample, 2),
            opt(r.train_gflops, 1),
            r.train_fraction_of_matmul
                .map_or("–".into(), |f| format!("{:.0} %", 100.0 * f)),
            opt(r.torch_ms_per_sample, 1),
            ratio_cell(r),
            r.frame_ms,
            opt(r.frame_gmac, 2),
        );
        if let Some(e) = &r.error {
            md += &format!("\n{}: {e}\n", r.method);
        }
    }
    md += &format!(
        "\nTraining ms per sample = the median timed step ({} steps × {} round(s) after one \
         untimed step per round) / batch.",
        a.steps, a.rounds
    );
    md += " Training GFLOP per sample = 3 × 2 × (backbone MACs + surface-branch MACs / batch); \
           grid sampling and the WarpingNet are left out (small). `linear` trains by a \
           closed-form fit: its figure is the whole fit divided by the pairs. PyTorch (with \
           --torch) runs the same network, loss, optimiser, sizes, batch and thread count from \
           scripts/bench_torch.py in this run.\n";
    if let Some(t) = rows.iter().find_map(|r| r.torch.as_ref()) {
        md += &format!("\nPyTorch: {t}.\n");
    }
    let jp = a.out.join("bench-train.json");
    compend::files::write_atomically(
        &jp,
        (serde_json::to_string_pretty(&json)? + "\n").as_bytes(),
    )?;
    let mp = a.out.join("bench-train.md");
    compend::files::write_atomically(&mp, md.as_bytes())?;
    print!("{md}");
    Ok(())
}
