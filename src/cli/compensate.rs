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
    /// SETUP/prj/cmp/test/MODEL. A file already there is replaced only when an earlier
    /// `compensate` wrote it (they are listed in the folder's `.compend-compensated`); never the
    /// inputs.
    #[arg(long)]
    pub out: PathBuf,
}

/// The list `compensate` keeps in its output folder of the images it wrote there, one name a
/// line after a header: a later run may replace those, and nothing else.
const MARKER: &str = ".compend-compensated";

pub fn run(args: Args) -> Result<()> {
    let model = Model::load(&args.model)?;
    let inputs = list_inputs(&args.input)?;
    // Names kept as they are (the list holds one per line): an input named otherwise is refused.
    let names: Vec<String> = inputs
        .iter()
        .map(|p| match p.file_name().and_then(|n| n.to_str()) {
            Some(n) if !n.contains('\n') => Ok(n.to_string()),
            _ => Err(compend::Error::Input(format!(
                "{}: a name that is not UTF-8 text on one line; rename it to compensate it",
                p.display()
            ))),
        })
        .collect::<compend::Result<_>>()?;
    let mut out = check_out(&args.out, &inputs)?;
    out.check(&names)?;
    out.claim(&names)?;
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

/// Whether `out` may take the compensation images of `inputs`: a folder (or nothing yet), not
/// the one the inputs are in, where a file of one of their names is there only if an earlier
/// `compensate` wrote it ([`MARKER`]). Returns the folder with the names its marker lists.
/// Input errors name the path.
fn check_out(out: &Path, inputs: &[PathBuf]) -> Result<super::OwnedOut> {
    super::check_out_folder(out, "--out")?;
    let here = out.canonicalize().ok();
    if let Some(p) = inputs.iter().find(|p| {
        let dir = p.parent().map(|d| {
            if d.as_os_str().is_empty() {
                Path::new(".")
            } else {
                d
            }
        });
        here.is_some() && dir.and_then(|d| d.canonicalize().ok()) == here
    }) {
        return Err(compend::Error::Input(format!(
            "{}: the folder of the input {}; the compensation images would replace the inputs: \
             choose another --out",
            out.display(),
            p.display()
        ))
        .into());
    }
    Ok(super::OwnedOut::open(
        out,
        "--out",
        MARKER,
        "compend compensate",
    )?)
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
        .filter(|p| p.extension().is_some_and(|e| e.eq_ignore_ascii_case("png")))
        .collect();
    // A name of an image that is no image (a folder, a FIFO, a broken link) is not skipped
    // quietly.
    if let Some(odd) = out.iter().find(|p| !p.is_file()) {
        return Err(compend::Error::Input(format!(
            "{}: not a regular file (a folder, a FIFO, a device or a broken link), in the input \
             folder of images",
            odd.display()
        ))
        .into());
    }
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
