//! Finding cameras: which cameras the machine has, by index and name, through nokhwa's query
//! of the platform's native camera API (V4L2 on Linux, AVFoundation on macOS, Media Foundation
//! on Windows). This is the portable half of the camera layer: on Linux each camera found is
//! then opened at its device node by [`super::v4l2`] for formats, controls and buffers.
//!
//! nokhwa's Linux query walks `/dev` for names starting with `video` and takes the digits of
//! each name as its index; a node named otherwise (a udev rule's `/dev/video-cam` link, a name
//! that is not UTF-8) makes it panic. Such a `/dev` is scanned here instead
//! ([`super::list::video_nodes`]), so finding never panics.

use std::path::{Path, PathBuf};

use serde::Serialize;

use crate::error::{Error, Result};

/// One camera the platform reports.
#[derive(Clone, Debug, PartialEq, Eq, Serialize)]
pub struct FoundCamera {
    /// The platform's index (on Linux N of /dev/videoN).
    pub index: u32,
    /// The camera's name ("HD Pro Webcam C920"); the device path when it has none.
    pub name: String,
    /// The device node, where the platform has one (Linux).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub path: Option<PathBuf>,
}

/// The cameras found, in index order. A machine without a camera gives an empty list; a
/// platform nokhwa cannot query is an error.
pub fn find() -> Result<Vec<FoundCamera>> {
    #[cfg(target_os = "linux")]
    if !nokhwa_can_scan(Path::new("/dev")) {
        tracing::debug!(
            "/dev holds a video* name that is not videoN: scanning it here instead of through \
             nokhwa"
        );
        return Ok(scan_dev(Path::new("/dev")));
    }
    let backend = nokhwa::native_api_backend().ok_or_else(|| {
        Error::Input(format!(
            "cameras cannot be found on {}: nokhwa has no camera API for it",
            std::env::consts::OS
        ))
    })?;
    let found = nokhwa::query(backend)
        .map_err(|e| Error::Failed(format!("finding cameras ({backend}): {e}")))?;
    let mut cameras: Vec<FoundCamera> = found
        .into_iter()
        .filter_map(|info| {
            let index = info.index().as_index().ok()?;
            Some(FoundCamera {
                index,
                name: info.human_name(),
                path: node_path(index),
            })
        })
        .collect();
    cameras.sort_by_key(|c| c.index);
    // A link named like a node (/dev/video0 and a /dev/video_0 link) is one camera.
    cameras.dedup_by_key(|c| c.index);
    Ok(cameras)
}

#[cfg(target_os = "linux")]
fn node_path(index: u32) -> Option<PathBuf> {
    Some(PathBuf::from(format!("/dev/video{index}")))
}

#[cfg(not(target_os = "linux"))]
fn node_path(_index: u32) -> Option<PathBuf> {
    None
}

/// Whether nokhwa's Linux query can walk `dir` without panicking: every name starting with
/// `video` is UTF-8 and `video` followed by a number.
pub fn nokhwa_can_scan(dir: &Path) -> bool {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return true;
    };
    entries.flatten().all(|e| {
        let name = e.file_name();
        let bytes = name.as_encoded_bytes();
        if !bytes.starts_with(b"video") {
            return true;
        }
        name.to_str()
            .and_then(|n| n.strip_prefix("video"))
            .is_some_and(|digits| digits.parse::<u32>().is_ok())
    })
}

/// The `videoN` nodes of `dir` with the names sysfs gives them.
fn scan_dev(dir: &Path) -> Vec<FoundCamera> {
    super::list::video_nodes(dir)
        .into_iter()
        .filter_map(|path| {
            let index = path
                .file_name()?
                .to_str()?
                .strip_prefix("video")?
                .parse()
                .ok()?;
            let name = std::fs::read_to_string(format!("/sys/class/video4linux/video{index}/name"))
                .map(|n| n.trim().to_string())
                .unwrap_or_else(|_| path.display().to_string());
            Some(FoundCamera {
                index,
                name,
                path: Some(path),
            })
        })
        .collect()
}

/// The device a `--camera` value names: a path as given (a /dev/videoN, a stable
/// /dev/v4l/by-id/ link); a number, the camera of that index; other text, the one camera whose
/// name contains it (case-insensitive), among those [`find`] finds.
pub fn resolve(spec: &Path) -> Result<PathBuf> {
    if is_path(spec) {
        return Ok(spec.to_path_buf());
    }
    resolve_in(spec, &find()?)
}

/// Whether a `--camera` value is a path (it holds a `/`) rather than an index or a name.
fn is_path(spec: &Path) -> bool {
    spec.to_str().is_none_or(|t| t.contains('/'))
}

/// [`resolve`] among the cameras `found`.
pub fn resolve_in(spec: &Path, found: &[FoundCamera]) -> Result<PathBuf> {
    let Some(text) = spec.to_str().filter(|_| !is_path(spec)) else {
        return Ok(spec.to_path_buf());
    };
    let listed = || {
        if found.is_empty() {
            "no camera was found".to_string()
        } else {
            let names: Vec<String> = found
                .iter()
                .map(|c| format!("{} \"{}\"", c.index, c.name))
                .collect();
            format!("the cameras found are {}", names.join(", "))
        }
    };
    let matches: Vec<&FoundCamera> = match text.parse::<u32>() {
        Ok(index) => found.iter().filter(|c| c.index == index).collect(),
        Err(_) => {
            let lower = text.to_lowercase();
            found
                .iter()
                .filter(|c| c.name.to_lowercase().contains(&lower))
                .collect()
        }
    };
    match matches.as_slice() {
        [one] => one.path.clone().ok_or_else(|| {
            Error::Input(format!(
                "camera \"{text}\" ({}) has no device node on {}; only Linux cameras can be \
                 opened",
                one.name,
                std::env::consts::OS
            ))
        }),
        [] => Err(Error::Input(format!(
            "camera \"{text}\": no camera has that index or a name containing it; {}. Give a \
             device path (/dev/videoN or /dev/v4l/by-id/...) or see `compend cameras`",
            listed()
        ))),
        many => Err(Error::Input(format!(
            "camera \"{text}\" matches {} cameras ({}); give its index or device path",
            many.len(),
            many.iter()
                .map(|c| format!("{} \"{}\"", c.index, c.name))
                .collect::<Vec<_>>()
                .join(", ")
        ))),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cams() -> Vec<FoundCamera> {
        [
            (0, "HD Pro Webcam C920"),
            (1, "HD Pro Webcam C920"),
            (4, "Integrated Camera"),
        ]
        .into_iter()
        .map(|(index, name)| FoundCamera {
            index,
            name: name.into(),
            path: Some(PathBuf::from(format!("/dev/video{index}"))),
        })
        .collect()
    }

    #[test]
    fn a_camera_is_named_by_path_index_or_part_of_its_name() {
        let c = cams();
        let path = Path::new("/dev/v4l/by-id/usb-cam-video-index0");
        assert_eq!(resolve_in(path, &c).unwrap(), path);
        assert_eq!(
            resolve_in(Path::new("4"), &c).unwrap(),
            Path::new("/dev/video4")
        );
        assert_eq!(
            resolve_in(Path::new("integrated"), &c).unwrap(),
            Path::new("/dev/video4")
        );
        let e = resolve_in(Path::new("c920"), &c).unwrap_err().to_string();
        assert!(e.contains("matches 2 cameras"), "{e}");
        let e = resolve_in(Path::new("7"), &c).unwrap_err().to_string();
        assert!(
            e.contains("0 \"HD Pro Webcam C920\"") && e.contains("compend cameras"),
            "{e}"
        );
        let e = resolve_in(Path::new("0"), &[]).unwrap_err().to_string();
        assert!(e.contains("no camera was found"), "{e}");
    }

    #[test]
    fn a_dev_with_a_video_name_nokhwa_would_panic_on_is_scanned_here() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("video0"), "").unwrap();
        std::fs::write(dir.path().join("null"), "").unwrap();
        assert!(nokhwa_can_scan(dir.path()));
        std::fs::write(dir.path().join("video-cam"), "").unwrap();
        assert!(!nokhwa_can_scan(dir.path()));
        let found = scan_dev(dir.path());
        assert_eq!(found.len(), 1);
        assert_eq!(found[0].index, 0);
    }
}
