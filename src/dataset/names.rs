//! File names and folder scans of the dataset layout (docs/architecture.md, "Dataset layout"):
//! official `img_NNNN.png` names, the indexed files of a folder and their contiguous run, path
//! and name checks shared by the data root and the setup.

use std::fs;
use std::path::{Path, PathBuf};

use crate::error::{Error, Result};
use crate::pngio;

pub(super) fn absolute(p: &Path) -> Result<PathBuf> {
    std::path::absolute(p).map_err(|e| Error::io(p, "resolve path", e))
}

pub(super) fn check_index(index: usize) -> Result<()> {
    if index == 0 {
        return Err(Error::Input(
            "image indices are 1-based (img_0001.png is the first)".into(),
        ));
    }
    Ok(())
}

pub(super) fn check_plain_name(name: &str, what: &str) -> Result<()> {
    let bad = name.is_empty()
        || name == "."
        || name == ".."
        || name.contains('/')
        || name.contains('\\')
        || name.contains('\0');
    if bad {
        return Err(Error::Input(format!(
            "{what} {name:?}: expected a plain name (no path separators, not . or ..)"
        )));
    }
    Ok(())
}

/// The 1-based index of an official file name `img_NNNN.png`, exactly as
/// [`pngio::indexed_name`] writes it (so `img_01.png` or `img_0000.png` are not indexed files).
pub fn parse_indexed_name(name: &str) -> Option<usize> {
    let digits = name.strip_prefix("img_")?.strip_suffix(".png")?;
    if digits.is_empty() || !digits.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    let i: usize = digits.parse().ok()?;
    (i >= 1 && pngio::indexed_name(i) == name).then_some(i)
}

/// The indexed files of a folder.
#[derive(Clone, Debug, Default)]
pub(crate) struct Scan {
    /// Sorted 1-based indices of the `img_NNNN.png` files present.
    pub indices: Vec<usize>,
}

impl Scan {
    /// Length of the run 1, 2, … n of present indices.
    pub fn contiguous(&self) -> usize {
        self.indices
            .iter()
            .enumerate()
            .take_while(|(k, i)| **i == k + 1)
            .count()
    }

    /// The gap error, when some index lies beyond the contiguous run.
    pub fn gap(&self, dir: &Path) -> Option<Error> {
        let n = self.contiguous();
        let later = *self.indices.get(n)?;
        Some(Error::Missing {
            path: dir.join(pngio::indexed_name(n + 1)),
            expected: format!(
                "the set must be numbered from img_0001.png without gaps; {} exists",
                pngio::indexed_name(later)
            ),
        })
    }
}

/// Lists the indexed files of `dir`; an absent folder is empty.
pub(crate) fn scan(dir: &Path) -> Result<Scan> {
    let entries = match fs::read_dir(dir) {
        Ok(e) => e,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(Scan::default()),
        Err(e) => return Err(Error::io(dir, "list folder", e)),
    };
    let mut indices = Vec::new();
    for entry in entries {
        let entry = entry.map_err(|e| Error::io(dir, "list folder", e))?;
        if let Some(i) = entry.file_name().to_str().and_then(parse_indexed_name) {
            indices.push(i);
        }
    }
    indices.sort_unstable();
    Ok(Scan { indices })
}

/// Images in `dir`, contiguous from 1; a gap is an error naming the first missing file.
/// Sorted 1-based indices of the `img_NNNN.png` files in `dir` (none when it is absent).
pub fn scan_indices(dir: &Path) -> Result<Vec<usize>> {
    Ok(scan(dir)?.indices)
}

/// Checks the closed-loop desired views `views` (sorted indices in `dir`) against a training
/// set of `last` pairs: the views must be the set's last pairs, one run without a gap up to
/// `last` (a calibration takes them after the sampling pairs). Views past `last` belong to
/// pairs not captured yet (a calibration interrupted between a view and its capture resumes
/// them) and are not checked. A gap in the run, or a run that stops before `last`, is an error
/// naming the first missing view.
pub(super) fn check_loop_views(dir: &Path, views: &[usize], last: usize) -> Result<()> {
    let Some(&first) = views.first().filter(|&&f| f <= last) else {
        return Ok(());
    };
    let Some(k) = (first..=last).find(|k| views.binary_search(k).is_err()) else {
        return Ok(());
    };
    let before = pngio::indexed_name(k - 1);
    let after = views.iter().find(|&&i| i > k).map_or_else(
        || {
            format!(
                "none after it, though the training set goes on to {}",
                pngio::indexed_name(last)
            )
        },
        |&i| format!("more from {}", pngio::indexed_name(i)),
    );
    Err(Error::Missing {
        path: dir.join(pngio::indexed_name(k)),
        expected: format!(
            "the desired view of training pair {k}: closed-loop pairs are the training set's \
             last pairs, one run with a view each, and this folder has views from {} to \
             {before}, then {after}",
            pngio::indexed_name(first)
        ),
    })
}

pub(super) fn count_dir(dir: &Path) -> Result<usize> {
    let s = scan(dir)?;
    match s.gap(dir) {
        Some(e) => Err(e),
        None => Ok(s.contiguous()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn indexed_names_round_trip_and_reject_others() {
        for i in [1, 42, 125, 126, 9999, 10000] {
            assert_eq!(parse_indexed_name(&pngio::indexed_name(i)), Some(i));
        }
        for bad in [
            "img_0000.png",
            "img_01.png",
            "img_00001.png",
            "img_gray.png",
            "img_0001.PNG",
            "img_0001.png.tmp",
            "x_0001.png",
            "img_+001.png",
        ] {
            assert_eq!(parse_indexed_name(bad), None, "{bad}");
        }
    }

    #[test]
    fn closed_loop_views_are_one_run_at_the_end_of_the_training_set() {
        let dir = Path::new("d");
        assert!(check_loop_views(dir, &[], 36).is_ok());
        assert!(check_loop_views(dir, &[25, 26, 27], 27).is_ok());
        // Views past the last capture: pairs not captured yet, as a resumed calibration has.
        assert!(check_loop_views(dir, &[25, 26, 27, 28], 27).is_ok());
        assert!(check_loop_views(dir, &[30], 27).is_ok());
        // The last view missing, a gap, a view for a sampling pair: the first missing file.
        for (views, missing, then) in [
            (
                &[25, 26][..],
                "img_0027.png",
                "none after it, though the training set goes on to img_0027.png",
            ),
            (&[25, 27][..], "img_0026.png", "more from img_0027.png"),
            (
                &[10, 25, 26, 27][..],
                "img_0011.png",
                "views from img_0010.png to img_0010.png, then more from img_0025.png",
            ),
        ] {
            let e = check_loop_views(dir, views, 27).unwrap_err();
            assert_eq!(e.exit_code(), 2);
            let e = e.to_string();
            assert!(e.starts_with(&format!("d/{missing}: missing")), "{e}");
            assert!(e.contains(then), "{e}");
        }
    }

    #[test]
    fn scan_counts_contiguous_run_and_names_first_gap() {
        let s = Scan {
            indices: vec![1, 2, 3, 5, 9],
        };
        assert_eq!(s.contiguous(), 3);
        let e = s.gap(Path::new("/d")).expect("a gap");
        let msg = e.to_string();
        assert!(msg.contains("/d/img_0004.png"), "{msg}");
        assert!(msg.contains("img_0005.png exists"), "{msg}");
        let s = Scan {
            indices: vec![2, 3],
        };
        assert_eq!(s.contiguous(), 0);
        assert!(
            s.gap(Path::new("/d"))
                .unwrap()
                .to_string()
                .contains("img_0001.png")
        );
        assert!(
            Scan {
                indices: vec![1, 2]
            }
            .gap(Path::new("/d"))
            .is_none()
        );
    }

    #[test]
    fn plain_names_only() {
        assert!(check_plain_name("compennet++", "m").is_ok());
        for bad in ["", ".", "..", "a/b", "a\\b"] {
            assert!(check_plain_name(bad, "m").is_err(), "{bad}");
        }
    }
}
