//! `compend compensate`: compensation images for desired camera-view images.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use compend::model::Model;
use compend::pngio;
use compend::raster::Camera;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// The model directory.
    #[arg(long)]
    pub model: PathBuf,
    /// A desired camera-view PNG, or a folder of them (e.g. SETUP/cam/desire/test).
    #[arg(long)]
    pub input: PathBuf,
    /// Folder for the network-space compensation PNGs (same file names as the inputs), e.g.
    /// SETUP/prj/cmp/test/MODEL.
    #[arg(long)]
    pub out: PathBuf,
}

pub fn run(args: Args) -> Result<()> {
    let model = Model::load(&args.model)?;
    let inputs = list_inputs(&args.input)?;
    for path in &inputs {
        let img =
            pngio::read_rgb_sized::<Camera>(path, model.camera_size(), "the model's camera size")?;
        let out = model.infer(&img)?;
        let name = path.file_name().context("input has a file name")?;
        let dest = args.out.join(name);
        pngio::write_rgb(&dest, &out).with_context(|| format!("writing {}", dest.display()))?;
    }
    eprintln!(
        "wrote {} compensation image(s) to {}",
        inputs.len(),
        args.out.display()
    );
    Ok(())
}

fn list_inputs(input: &Path) -> Result<Vec<PathBuf>> {
    if input.is_file() {
        return Ok(vec![input.to_path_buf()]);
    }
    if !input.is_dir() {
        return Err(compend::Error::Missing {
            path: input.to_path_buf(),
            expected: "a PNG file or a folder of PNGs".into(),
        }
        .into());
    }
    let mut out: Vec<PathBuf> = std::fs::read_dir(input)
        .map_err(|e| compend::Error::io(input, "list folder", e))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.is_file() && p.extension().is_some_and(|e| e.eq_ignore_ascii_case("png")))
        .collect();
    out.sort();
    if out.is_empty() {
        return Err(compend::Error::Input(format!(
            "{}: no PNG files in this folder",
            input.display()
        ))
        .into());
    }
    Ok(out)
}
