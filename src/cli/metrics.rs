//! `compend metrics A B [--json]`: PSNR, RMSE and SSIM of two PNGs or two folders of same-named PNGs.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use compend::metrics::Accumulator;
use compend::pngio;
use compend::raster::Unspecified;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// First image, or a folder of PNGs (e.g. the captured or compensated results).
    pub a: PathBuf,
    /// Second image, or a folder holding the same PNG names as A (a name in one folder only
    /// is an error).
    pub b: PathBuf,
    /// Print one JSON object {"psnr", "rmse", "ssim", "n"} on stdout instead of a table.
    #[arg(long)]
    pub json: bool,
}

pub fn run(args: Args) -> Result<()> {
    let pairs = pair_paths(&args.a, &args.b)?;
    let mut acc = Accumulator::default();
    for (pa, pb) in &pairs {
        let a = pngio::read_rgb::<Unspecified>(pa)?;
        let b = pngio::read_rgb::<Unspecified>(pb)?;
        if a.size() != b.size() {
            return Err(compend::Error::Size {
                path: pb.clone(),
                got: b.size(),
                expected: a.size(),
                why: format!("the size of {}", pa.display()),
            }
            .into());
        }
        acc.add(&a, &b)
            .with_context(|| format!("comparing {} with {}", pa.display(), pb.display()))?;
    }
    let s = acc.finish()?;
    if args.json {
        println!("{}", serde_json::to_string(&s)?);
    } else {
        println!("PSNR  {:.4} dB", s.psnr);
        println!("RMSE  {:.6}", s.rmse);
        println!("SSIM  {:.6}", s.ssim);
        println!("pairs {}", s.n);
    }
    Ok(())
}

/// Matches A and B: two files, or every `*.png` in folder A with the same name in folder B.
fn pair_paths(a: &Path, b: &Path) -> Result<Vec<(PathBuf, PathBuf)>> {
    match (a.is_dir(), b.is_dir()) {
        (false, false) => Ok(vec![(a.to_path_buf(), b.to_path_buf())]),
        (true, true) => {
            let names = png_names(a)?;
            if names.is_empty() {
                return Err(compend::Error::Input(format!(
                    "{}: no PNG files in this folder",
                    a.display()
                ))
                .into());
            }
            // Every PNG must have its counterpart, whichever folder comes first: a score over
            // fewer pairs than a folder holds would pass for the whole folder's.
            let extra: Vec<String> = png_names(b)?
                .into_iter()
                .filter(|n| !names.contains(n))
                .collect();
            if let Some(first) = extra.first() {
                return Err(compend::Error::Missing {
                    path: a.join(first),
                    expected: format!(
                        "the counterpart of {} ({} PNG{} of {} have none in {}); compare \
                         folders holding the same names",
                        b.join(first).display(),
                        extra.len(),
                        if extra.len() == 1 { "" } else { "s" },
                        b.display(),
                        a.display()
                    ),
                }
                .into());
            }
            names
                .into_iter()
                .map(|n| {
                    let pb = b.join(&n);
                    if pb.is_file() {
                        Ok((a.join(&n), pb))
                    } else {
                        Err(compend::Error::Missing {
                            path: pb,
                            expected: format!("the counterpart of {}", a.join(&n).display()),
                        }
                        .into())
                    }
                })
                .collect()
        }
        _ => Err(compend::Error::Input(format!(
            "{} and {} must both be PNG files or both be folders",
            a.display(),
            b.display()
        ))
        .into()),
    }
}

/// Sorted names of the `.png` files directly in `dir`; a `.png` name that is not a regular
/// file is an input error.
fn png_names(dir: &Path) -> Result<Vec<String>> {
    let mut names = Vec::new();
    let entries = std::fs::read_dir(dir).map_err(|e| compend::Error::io(dir, "list folder", e))?;
    for entry in entries {
        let entry = entry.map_err(|e| compend::Error::io(dir, "list folder", e))?;
        let name = entry.file_name().to_string_lossy().into_owned();
        if !name.to_ascii_lowercase().ends_with(".png") {
            continue;
        }
        // A name of an image that is no image is not skipped quietly.
        if !entry.path().is_file() {
            return Err(compend::Error::Input(format!(
                "{}: not a regular file (a folder, a FIFO, a device or a broken link), among \
                 the images to compare",
                entry.path().display()
            ))
            .into());
        }
        names.push(name);
    }
    names.sort();
    Ok(names)
}
