//! `compend eval`: the paper protocol on a setup's validation pairs, with the uncompensated row.

use std::path::PathBuf;

use anyhow::{Context, Result};
use compend::metrics::Scores;
use compend::model::Model;
use serde_json::json;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// The model directory.
    #[arg(long)]
    pub model: PathBuf,
    #[command(flatten)]
    pub setup: super::SetupArgs,
    /// Print one JSON object on stdout.
    #[arg(long)]
    pub json: bool,
}

pub fn run(args: Args) -> Result<()> {
    let model = Model::load(&args.model)?;
    let setup = args.setup.open()?;
    let pairs = setup.load_test(None)?;
    let gray = setup.reference_path(compend::dataset::Reference::Gray);
    if !gray.is_file() {
        tracing::warn!(
            "{}: missing (the gray surface capture); the test pairs are scored without it, \
             but the setup is incomplete (see `compend inspect`)",
            gray.display()
        );
    }
    let camera = setup.camera_size()?;
    if camera != model.camera_size() {
        return Err(compend::Error::Input(format!(
            "{}: camera images are {}, the model {} was trained on {}",
            setup.path().display(),
            camera,
            args.model.display(),
            model.camera_size()
        ))
        .into());
    }
    let (comp, uncomp) = compend::model::paper_protocol(&model, &pairs)
        .with_context(|| format!("scoring the test pairs of {}", setup.path().display()))?;
    let forward = compend::model::forward_mse(&model, &pairs)
        .with_context(|| format!("scoring the test pairs of {}", setup.path().display()))?
        .map(compend::metrics::psnr_from_mse);
    let method = model.meta.method.name();
    if args.json {
        println!(
            "{}",
            json!({ "method": method, "model": args.model, "setup": setup.path(),
                    "n": comp.n, "compensated": comp, "uncompensated": uncomp,
                    "camera_space_psnr": forward })
        );
    } else {
        println!("{:<16} {:>9} {:>9} {:>9}", "row", "PSNR", "RMSE", "SSIM");
        let row = |name: &str, s: &Scores| {
            println!("{name:<16} {:>9.4} {:>9.4} {:>9.4}", s.psnr, s.rmse, s.ssim);
        };
        row("uncompensated", &uncomp);
        row(method, &comp);
        if let Some(db) = forward {
            println!(
                "{:<16} {db:>9.4}   (camera space: the model's prediction of each capture)",
                "forward"
            );
        }
        let out = model.network_size();
        let net = pairs.inputs.first().map_or(out, |i| i.size());
        if out == net {
            println!("({} test pairs, network {net})", comp.n);
        } else {
            println!(
                "({} test pairs; model output {out}, scored at the network size {net})",
                comp.n
            );
        }
    }
    Ok(())
}
