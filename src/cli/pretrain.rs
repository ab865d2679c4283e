//! `compend pretrain`: the photometric pre-initialisation of CompenNet (docs/architecture.md,
//! "Models").
//!
//! The shipped weights are reproduced by
//! `compend pretrain --width 16 --out weights/compennet-pretrain-w16.safetensors` and the same
//! with `--width 32` (every other setting at its default, which is what the JSON beside each file
//! records).

use std::path::PathBuf;
use std::sync::atomic::AtomicBool;

use anyhow::{Context, Result};
use compend::nn::pretrain::{self, PretrainSettings};

#[derive(clap::Args, Debug)]
pub struct Args {
    /// CompenNet's base channel width: 32 for the paper's network (the `compennet++` variants),
    /// 16 for `compennet++-cpu`.
    #[arg(long)]
    pub width: usize,
    /// Weight file to write (safetensors); its metadata goes beside it as `.json`. An existing
    /// file is replaced only once the new one is complete.
    #[arg(long)]
    pub out: PathBuf,
    /// Seed of the synthetic images, the crops and the initial weights.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Iterations (the learning-rate step stays at 4/5 of them).
    #[arg(long)]
    pub iters: Option<usize>,
    /// Crops per iteration.
    #[arg(long)]
    pub batch: Option<usize>,
    /// Learning rate of Adam (×0.2 at 4/5 of the iterations).
    #[arg(long)]
    pub lr: Option<f64>,
    /// Side of the square crops, network pixels (a multiple of 4).
    #[arg(long)]
    pub patch: Option<usize>,
    /// Print one JSON summary on stdout.
    #[arg(long)]
    pub json: bool,
}

pub fn run(args: Args) -> Result<()> {
    let mut settings = PretrainSettings::shipped(args.width);
    settings.seed = args.seed;
    if let Some(n) = args.iters {
        settings.iters = n;
        settings.lr_step = n * 4 / 5;
    }
    if let Some(b) = args.batch {
        settings.batch = b;
    }
    if let Some(lr) = args.lr {
        settings.learning_rate = lr;
    }
    if let Some(p) = args.patch {
        settings.patch = p;
        settings.image = settings.image.max(2 * p);
    }
    check_weights_out(&args.out)?;
    let bar = super::progress_bar(args.json);
    bar.set_message("pretrain");
    let never = AtomicBool::new(false);
    let weights = pretrain::pretrain(
        &settings,
        &candle_core::Device::Cpu,
        &never,
        |done, total, loss| {
            bar.set_length(total as u64);
            bar.set_position(done as u64);
            bar.set_message(format!("loss {loss:.3}"));
        },
    )
    .with_context(|| format!("pre-training CompenNet of width {}", args.width))?;
    bar.finish_and_clear();
    weights
        .save(&args.out)
        .with_context(|| format!("saving the weights to {}", args.out.display()))?;
    let m = &weights.meta;
    if args.json {
        println!(
            "{}",
            serde_json::json!({"out": args.out, "width": args.width, "first_loss": m.first_loss,
                               "final_loss": m.final_loss, "seconds": m.seconds})
        );
    } else {
        eprintln!(
            "pre-trained CompenNet width {} in {:.1} s: loss {:.4} → {:.4} (means of the first and last 50 iterations); weights: {}",
            args.width,
            m.seconds,
            m.first_loss,
            m.final_loss,
            args.out.display()
        );
    }
    Ok(())
}

/// Before any work: `--out` may only replace an earlier weights file (a readable safetensors
/// file), never a folder or a file of something else, and its folder must be writable.
fn check_weights_out(out: &std::path::Path) -> compend::Result<()> {
    match std::fs::symlink_metadata(out) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
        Err(e) => return Err(compend::Error::io(out, "inspect the output path", e)),
        Ok(m) if !m.is_file() => {
            return Err(compend::Error::Input(format!(
                "{}: not a file; --out names the weights file to write (FILE.safetensors)",
                out.display()
            )));
        }
        Ok(_) => {
            let bytes = compend::files::read_regular(
                out,
                "a weights file (safetensors)",
                compend::files::MAX_WEIGHTS_BYTES,
            )?;
            if safetensors::SafeTensors::deserialize(&bytes).is_err() {
                return Err(compend::Error::Input(format!(
                    "{}: exists and is not a safetensors file; only earlier weights are \
                     replaced: choose another --out or move it away",
                    out.display()
                )));
            }
        }
    }
    compend::files::check_writable(out)
}
