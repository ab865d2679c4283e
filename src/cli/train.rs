//! `compend train`: fit a model on a setup's training pairs and write the model directory.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result};
use compend::dataset::{Reference, Setup};
use compend::fov;
use compend::linear::{self, FitSettings};
use compend::model::Model;
use compend::modeldir::{FORMAT_VERSION, ModelMeta};
use compend::raster::{CamImage, NetImage};
use serde_json::json;

use super::InputError;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// The setup folder (holding cam/raw/...).
    #[arg(long)]
    pub setup: PathBuf,
    /// The data root holding train/ and test/ (default: the nearest ancestor of the setup that has them).
    #[arg(long)]
    pub data: Option<PathBuf>,
    /// Model to fit: `linear` (learned geometry + per-pixel linear colour) or `linear-sl`
    /// (geometry from the setup's structured-light captures cam/raw/sl, then the same colour model).
    #[arg(long)]
    pub method: String,
    /// Number of training pairs to use (the first N). Default: all available, at most 48.
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
}

/// Fewest training pairs the `linear` fit accepts: each network pixel has 12 colour coefficients.
const MIN_TRAIN: usize = 4;
const DEFAULT_TRAIN: usize = 48;
const SL_METHOD: &str = "linear-sl";

/// The network→camera grid from the setup's structured-light captures; the network image is
/// assumed stretched over the whole projector frame (the size of the root's sl/ patterns).
fn sl_grid(
    setup: &Setup,
    network_size: (usize, usize),
) -> Result<compend::sample::Grid<compend::raster::Network, compend::raster::Camera>> {
    let projector = setup.root().projector_size()?;
    let code = compend::patterns::GrayCode::new(projector.0, projector.1)?;
    let captures = setup.load_captures(compend::dataset::CaptureSet::Sl, None)?;
    if captures.len() != code.len() {
        return Err(InputError(format!(
            "{}: {} structured-light captures, expected {} for a {}x{} projector",
            setup
                .capture_dir(compend::dataset::CaptureSet::Sl)
                .display(),
            captures.len(),
            code.len(),
            projector.0,
            projector.1
        ))
        .into());
    }
    let corr = code.decode(&captures)?;
    let canvas = compend::raster::Rect {
        x: 0,
        y: 0,
        width: projector.0,
        height: projector.1,
    };
    let sl = compend::slgrid::grid_from_correspondence(&corr, canvas, network_size)?;
    Ok(sl.grid)
}

pub fn run(args: Args) -> Result<()> {
    let start = Instant::now();
    if !compend::model::METHODS.contains(&args.method.as_str()) {
        return Err(InputError(format!(
            "--method {}: not available; methods: {}",
            args.method,
            compend::model::METHODS.join(", ")
        ))
        .into());
    }
    let setup = Setup::open(&args.setup, args.data.as_deref())?;
    let available = setup.count(compend::dataset::CaptureSet::Train)?;
    let ntrain = args.ntrain.unwrap_or(available.min(DEFAULT_TRAIN));
    if ntrain < MIN_TRAIN {
        return Err(InputError(format!(
            "--ntrain {ntrain}: the {} method needs at least {MIN_TRAIN} training pairs ({} has {available})",
            args.method,
            setup.capture_dir(compend::dataset::CaptureSet::Train).display()
        ))
        .into());
    }
    let black = setup.load_reference(Reference::Black)?;
    let white = setup.load_reference(Reference::White)?;
    let label = format!(
        "{} and {}",
        setup.reference_path(Reference::Black).display(),
        setup.reference_path(Reference::White).display()
    );
    let fov = fov::fov_mask(&black, &white, &label)?;
    let cam_size = black.size();
    let theta = fov::affine_from_box(fov.bbox, cam_size)?;
    let pairs = setup.load_train(Some(ntrain))?;
    let network_size = pairs.inputs[0].size();
    let captures: Vec<CamImage> = pairs
        .captures
        .iter()
        .map(|c| c.masked(&fov.mask))
        .collect::<compend::Result<_>>()?;
    let targets: Vec<NetImage> = pairs.inputs.into_iter().map(|p| p.into_space()).collect();

    let settings = FitSettings {
        network_size,
        ..FitSettings::default()
    };
    let bar = super::progress_bar(args.json);
    let (fitted, report) = if args.method == SL_METHOD {
        bar.set_message("decoding structured light");
        let grid = sl_grid(&setup, network_size)?;
        linear::fit_on_grid(&captures, &targets, grid, &settings)
    } else {
        linear::fit(
            &captures,
            &targets,
            compend::warp::Warp::from_affine(theta),
            &settings,
            |stage, done, total| {
                bar.set_length(total as u64);
                bar.set_position(done as u64);
                bar.set_message(stage.to_string());
            },
        )
    }
    .with_context(|| format!("fitting the {} model", args.method))?;
    bar.finish_and_clear();

    let out = args
        .out
        .clone()
        .unwrap_or_else(|| setup.path().join("models").join(&args.method));
    let seconds = start.elapsed().as_secs_f64();
    let meta = ModelMeta {
        format_version: FORMAT_VERSION,
        method: args.method.clone(),
        network_size,
        camera_size: cam_size,
        canvas: None,
        training: json!({
            "setup": setup.path(),
            "data_root": setup.root().path(),
            "ntrain": ntrain,
            "seed": args.seed,
            "fov": fov.diagnostics,
            "fov_bbox": fov.bbox,
            "settings": settings,
            "curves": fitted.curves,
            "final_loss": report.final_loss,
        }),
        metrics: serde_json::Value::Null,
        timings: json!({ "fit_seconds": report.seconds, "train_seconds": seconds }),
        written_by: format!("compend {}", env!("CARGO_PKG_VERSION")),
    };
    let final_loss = report.final_loss;
    if !final_loss.is_finite() {
        return Err(anyhow::anyhow!(
            "training diverged (final loss {final_loss}); no model written"
        ));
    }
    Model::linear(meta, fov.mask, fitted)
        .save(&out)
        .with_context(|| format!("saving the model to {}", out.display()))?;
    let seconds = start.elapsed().as_secs_f64();
    if args.json {
        println!(
            "{}",
            json!({"method": args.method, "ntrain": ntrain, "seconds": seconds,
                   "final_loss": final_loss, "model": out})
        );
    } else {
        eprintln!(
            "trained {} on {ntrain} pairs in {seconds:.1} s (loss {final_loss:.3e}); model: {}",
            args.method,
            out.display()
        );
    }
    Ok(())
}
