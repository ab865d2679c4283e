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
const MARKER_HEADER: &str = "# compensation images written by `compend compensate`";

pub fn run(args: Args) -> Result<()> {
    let model = Model::load(&args.model)?;
    let inputs = list_inputs(&args.input)?;
    let mut ours = check_out(&args.out, &inputs)?;
    std::fs::create_dir_all(&args.out)
        .map_err(|e| compend::Error::io(&args.out, "create folder", e))?;
    // Listed before they are written: a run stopped half-way may be run again.
    ours.extend(
        inputs
            .iter()
            .filter_map(|p| p.file_name())
            .map(|n| n.to_string_lossy().into_owned()),
    );
    let list: String = std::iter::once(MARKER_HEADER.to_string())
        .chain(ours)
        .map(|l| l + "\n")
        .collect();
    compend::files::write_atomically(&args.out.join(MARKER), list.as_bytes())?;
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
/// `compensate` wrote it ([`MARKER`]). Returns the names the marker lists. Input errors name
/// the path.
fn check_out(out: &Path, inputs: &[PathBuf]) -> Result<std::collections::BTreeSet<String>> {
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
    let marker = out.join(MARKER);
    let ours: std::collections::BTreeSet<String> = match std::fs::read_to_string(&marker) {
        Ok(text) => text
            .lines()
            .filter(|l| !l.is_empty() && !l.starts_with('#'))
            .map(str::to_string)
            .collect(),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Default::default(),
        Err(e) => return Err(compend::Error::io(&marker, "read", e).into()),
    };
    if let Some(dest) = inputs
        .iter()
        .filter_map(|p| p.file_name())
        .filter(|n| !ours.contains(n.to_string_lossy().as_ref()))
        .map(|n| out.join(n))
        .find(|d| d.exists())
    {
        return Err(compend::Error::Input(format!(
            "{}: already there, and not written by `compend compensate` (not listed in {}), so \
             it is not replaced: choose another --out (or, if an older compend wrote it, remove \
             it)",
            dest.display(),
            marker.display()
        ))
        .into());
    }
    Ok(ours)
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
