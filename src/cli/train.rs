//! `compend train`: fit a model on a setup's training pairs and write the model directory.

use std::path::PathBuf;

use anyhow::{Context, Result};
use compend::fit::{self, Request};
use compend::raster::ImageSize;
use serde_json::json;

#[derive(clap::Args, Debug)]
pub struct Args {
    #[command(flatten)]
    pub setup: super::SetupArgs,
    /// The rung to fit (listed below). CompenNet++ on a 2-core CPU takes about 0.45–0.5 s per
    /// 256² sample (`compennet++-cpu`: about 4–4.5 minutes in all): see --iters. `auto` fits
    /// `linear` and `linear-sl` on all but a sixth of the sampling pairs and scores them on the
    /// held-out ones (paper-protocol PSNR); then trains the CompenNet++ rung the device affords
    /// (`compennet++-res` on the CPU, `compennet++-res-full` with --device cuda), scoring it
    /// on held-out pairs as it trains, and climbs to it only if it beats the rung below by
    /// --climb-gain: the rung is then trained again on the held-out pairs too (every pair when
    /// judged on closed-loop pairs, every sampling pair otherwise). Otherwise it refits the best
    /// linear rung on all pairs. On a setup with 8 or more closed-loop pairs (a calibration's)
    /// that rung is judged on the last sixth of those, held out of its training, against its
    /// own linear part; otherwise on the sampling pairs held out. The evidence goes into
    /// model.json.
    #[arg(long, value_enum)]
    pub method: compend::model::MethodChoice,
    /// Number of training pairs to use (the first N). Default: all available, at most 48 (the
    /// full CompenNet++: its schedule's 500), and for linear, linear-sl, the residual rungs
    /// (compennet++-res, compennet++-res-full) and auto up to the last closed-loop pair a
    /// calibration took (cam/desire/train).
    #[arg(long)]
    pub ntrain: Option<usize>,
    /// Seed for every random choice of the fit (recorded in the model).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Model directory to write (default: SETUP/models/METHOD). An existing model there is
    /// replaced only once the new one is complete.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Print one JSON summary on stdout.
    #[arg(long)]
    pub json: bool,
    #[command(flatten)]
    pub network: super::NetworkFlags,
    /// `auto` only: the PSNR gain in dB on held-out pairs the CompenNet++ rung needs over the
    /// best linear rung to be chosen [default: 0.5].
    #[arg(long, value_name = "DB", allow_hyphen_values = true)]
    pub climb_gain: Option<f64>,
    /// The linear rungs (and the residual rungs' linear part): the lattice of the per-pixel
    /// colour model and of the compensation images, `N` or `WxH`, or `native`: the projector's
    /// resolution (the size of the data root's structured-light patterns). Default: the
    /// projector's resolution, scaled down to at most 1920×1080 pixels; 1.5× the network size
    /// where the root has no structured-light patterns. The network size itself reproduces the
    /// paper's 256² output. Live playback stretches any lattice over the canvas; offline,
    /// `compensate` writes images of this size.
    #[arg(long, value_name = "N|WxH|native", value_parser = parse_lattice)]
    pub lattice: Option<Lattice>,
    /// The projector's resolution, WxH, for the default lattice and for `auto`'s live pass,
    /// when the data does not give it (a dataset in the CompenNet++ layout has no
    /// structured-light patterns and no calibration record). The output says which lattice
    /// was used and why.
    #[arg(long, value_name = "WxH", value_parser = super::sim::parse_size)]
    pub projector: Option<compend::raster::ImageSize>,
    /// CompenNet++ variants: how CompenNet's weights start: `shipped` (the photometric
    /// pre-initialisation compiled into compend, see `compend pretrain`), `none` (Kaiming noise
    /// from --seed, as the paper without pre-training) or a `.safetensors` file written by
    /// `compend pretrain` for the variant's channel width.
    #[arg(long, value_name = "shipped|none|FILE", default_value = "shipped")]
    pub photometric_init: compend::nn::pretrain::PhotometricInit,
    /// `auto` only: weigh the climb's live pass for a display refreshing at HZ. The rung it
    /// would climb to is timed first on this machine's GPU, at the setup's projector resolution
    /// (a setup that does not record it is refused), and is not trained when its pass takes
    /// more than half of one refresh period, or cannot be timed. Default, or 0: not weighed
    /// (the model may play on another machine); `calibrate` weighs it on the projector
    /// window's GPU.
    #[arg(long, value_name = "HZ", allow_hyphen_values = true)]
    pub refresh_hz: Option<f64>,
}

pub fn run(args: Args) -> Result<()> {
    let setup = args.setup.open()?;
    let out = args
        .out
        .clone()
        .unwrap_or_else(|| setup.path().join("models").join(args.method.name()));
    // Before any work: only a model directory is ever replaced, and the place must be writable.
    compend::model::store::check_output(&out)?;
    // Not into a running service's model path.
    let _lock = super::lock_model_state(&out, &[], "train")?;
    let req = Request {
        ntrain: args.ntrain,
        seed: args.seed,
        iters: args.network.iters,
        batch: args.network.batch,
        device: args.network.device,
        lattice: match args.lattice {
            None => None,
            Some(Lattice::Size(s)) => Some(s),
            // The projector's own resolution: the size of the root's structured-light patterns.
            Some(Lattice::Native) => Some(setup.root().projector_size().with_context(|| {
                format!(
                    "--lattice native: the projector's size comes from {}",
                    setup.root().path().display()
                )
            })?),
        },
        projector: args.projector,
        photometric: args.photometric_init.clone(),
        climb_gain_db: args.climb_gain,
        live: super::refresh_timer(
            args.refresh_hz,
            args.method == compend::model::MethodChoice::Auto,
            &format!("{} is one rung", args.method),
        )?,
        ..Request::new(args.method)
    };
    if let Some(w) = args
        .climb_gain
        .and_then(|g| fit::ClimbRule { gain_db: g }.caveat("--climb-gain"))
    {
        eprintln!("warning: {w}");
    }
    // Which lattice the linear rungs' output takes, and why (the data may not say the
    // projector's size).
    let lattice_rung = match args.method {
        compend::model::MethodChoice::Auto => true,
        compend::model::MethodChoice::Rung(m) => m.is_linear() || m.is_residual(),
    };
    if lattice_rung {
        let (lattice, why) = fit::lattice_choice(&setup, &req)
            .with_context(|| format!("the output lattice for {}", setup.path().display()))?;
        eprintln!("train: output lattice {lattice}: {why}");
    }
    let report = super::progress::Progress::new("train", args.json);
    let (model, summary) = fit::fit(&setup, &req, |stage, done, total| {
        report.update(stage, done, total)
    })
    .with_context(|| format!("training {} on {}", args.method, setup.path().display()))?;
    report.finish();
    model
        .save(&out)
        .with_context(|| format!("saving the model to {}", out.display()))?;
    if args.json {
        println!(
            "{}",
            json!({"method": summary.method, "ntrain": summary.ntrain, "seconds": summary.seconds,
                   "fit_seconds": summary.fit_seconds, "final_loss": summary.final_loss, "model": out,
                   "auto": model.meta.training.auto})
        );
    } else {
        for line in model
            .meta
            .training
            .auto
            .iter()
            .flat_map(compend::fit::evidence_lines)
        {
            eprintln!("{line}");
        }
        eprintln!(
            "trained {} on {} pairs in {:.1} s (loss {:.3e}); model: {}",
            summary.method,
            summary.ntrain,
            summary.seconds,
            summary.final_loss,
            out.display()
        );
    }
    Ok(())
}

/// `--lattice`: a size, or `native` (the projector's, resolved from the setup).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Lattice {
    Size(ImageSize),
    Native,
}

fn parse_lattice(s: &str) -> std::result::Result<Lattice, String> {
    if s == "native" {
        return Ok(Lattice::Native);
    }
    super::patterns::parse_wxh(s, true).map(Lattice::Size)
}
