//! Loading helpers shared by the data root and the setup: requested counts against what a
//! folder holds, parallel reading with size checks, and naming the file that set a wrong size.
//! Sizes are (width, height) in pixels of the space named.

use std::path::{Path, PathBuf};

use crate::error::{Error, Result};
use crate::pngio;
use crate::raster::{ImageSize, Rgb, Space};

/// Resolves a requested count against what `dir` holds.
pub(super) fn take_count(
    dir: &Path,
    have: usize,
    want: Option<usize>,
    what: &str,
) -> Result<usize> {
    match want {
        None => Ok(have),
        Some(n) if n <= have => Ok(n),
        Some(n) => Err(Error::Input(format!(
            "{}: holds {have} {what}{}, but {n} were requested",
            dir.display(),
            if have > 0 {
                format!(
                    " ({}..{})",
                    pngio::indexed_name(1),
                    pngio::indexed_name(have)
                )
            } else {
                String::new()
            }
        ))),
    }
}

/// Maps `f` over `items` in parallel (rayon), keeping the order.
pub(crate) fn par_map<T: Sync, R: Send>(items: &[T], f: impl Fn(&T) -> R + Sync + Send) -> Vec<R> {
    use rayon::prelude::*;
    items.par_iter().map(f).collect()
}

/// Reads every image of a group in parallel, each checked against `size` (set by the file
/// `setter`, for the reason `why`); the first error in path order wins. When an image has
/// another size and most of the group agrees with it, the setter is the odd one out: the error
/// names the setter, not the good image.
pub(super) fn read_all<S: Space>(
    paths: &[PathBuf],
    size: ImageSize,
    why: &str,
    setter: &Path,
) -> Result<Vec<Rgb<S>>> {
    read_all_with(paths, setter, |p| pngio::read_rgb_sized::<S>(p, size, why))
}

/// [`read_all`], each image read by `read` (which checks its size).
pub(super) fn read_all_with<T: Send>(
    paths: &[PathBuf],
    setter: &Path,
    read: impl Fn(&Path) -> Result<T> + Sync + Send,
) -> Result<Vec<T>> {
    par_map(paths, |p| {
        if !p.is_file() {
            return Err(Error::Missing {
                path: p.clone(),
                expected: "an image of the set".into(),
            });
        }
        read(p)
    })
    .into_iter()
    .collect::<Result<Vec<_>>>()
    .map_err(|e| match e {
        Error::Size { got, .. } => blame_the_odd_one(e, paths, got, setter),
        e => e,
    })
}

/// `err` said an image of `paths` is `got` instead of the setter's size. If more than half of
/// the group (read from the PNG headers) is `got`, the setter is the one that differs from the
/// majority: an error naming it instead.
pub(super) fn blame_the_odd_one(
    err: Error,
    paths: &[PathBuf],
    got: ImageSize,
    setter: &Path,
) -> Error {
    let sizes: Vec<ImageSize> = paths
        .iter()
        .filter(|p| p.as_path() != setter)
        .filter_map(|p| pngio::png_size(p).ok())
        .collect();
    let agree = sizes.iter().filter(|&&s| s == got).count();
    let Ok(setter_size) = pngio::png_size(setter) else {
        return err;
    };
    if setter_size == got || 2 * agree <= sizes.len() {
        return err;
    }
    Error::Size {
        path: setter.to_path_buf(),
        got: setter_size,
        expected: got,
        why: format!(
            "the size of {agree} of the {} other images it sets the size for, e.g. {}",
            sizes.len(),
            paths
                .iter()
                .find(|p| p.as_path() != setter)
                .map_or_else(String::new, |p| p.display().to_string())
        ),
    }
}
