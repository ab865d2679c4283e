//! What `compend cameras` shows: each V4L2 node with its driver and card name, formats with
//! frame sizes and rates, and controls with range and current value ([`CameraListing`]), as
//! text ([`render`]) or JSON (serde). Reading the devices is [`super::v4l2::list`].

use std::path::{Path, PathBuf};

use serde::Serialize;

use super::controls::{ControlInfo, ControlKind};
use super::format::FormatOffer;
use crate::error::Error;

/// One device node.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct CameraListing {
    pub path: PathBuf,
    /// The kernel driver (`uvcvideo`).
    pub driver: String,
    /// The device's name ("HD Pro Webcam C920").
    pub card: String,
    /// Where it is attached (`usb-0000:00:14.0-1`).
    pub bus: String,
    /// Whether the node captures video (a UVC camera's second node carries metadata only).
    pub capture: bool,
    pub formats: Vec<FormatOffer>,
    pub controls: Vec<ControlInfo>,
    /// Why the node could not be read (fully), if it could not.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
}

impl CameraListing {
    /// A node that could not be opened or queried: its path and the reason.
    pub fn unreadable(path: &Path, e: &Error) -> Self {
        Self {
            path: path.to_path_buf(),
            driver: String::new(),
            card: String::new(),
            bus: String::new(),
            capture: false,
            formats: Vec::new(),
            controls: Vec::new(),
            error: Some(e.to_string()),
        }
    }
}

/// The `videoN` nodes in `dir`, in number order (video2 before video10). Symbolic links and
/// other names (`/dev/video-cam`, `/dev/v4l/`) are left out: each device once.
pub fn video_nodes(dir: &Path) -> Vec<PathBuf> {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return Vec::new();
    };
    let mut nodes: Vec<(u32, PathBuf)> = entries
        .flatten()
        .filter(|e| e.file_type().is_ok_and(|t| !t.is_symlink()))
        .filter_map(|e| {
            let name = e.file_name();
            let n = name.to_str()?.strip_prefix("video")?.parse::<u32>().ok()?;
            Some((n, e.path()))
        })
        .collect();
    nodes.sort();
    nodes.into_iter().map(|(_, p)| p).collect()
}

/// Frame rates for a line: "30, 15, 7.5 fps" or "1–30 fps".
fn rates(fps: &[f64], range: bool) -> String {
    let n = |v: f64| {
        let s = format!("{v:.2}");
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    };
    match (fps, range) {
        ([], _) => String::new(),
        ([lo, hi], true) => format!(" @ {}–{} fps", n(*lo), n(*hi)),
        _ => format!(
            " @ {} fps",
            fps.iter().map(|v| n(*v)).collect::<Vec<_>>().join(", ")
        ),
    }
}

fn render_format(f: &FormatOffer, out: &mut Vec<String>) {
    out.push(format!("    {} \"{}\"", f.fourcc, f.description));
    for s in &f.sizes {
        out.push(format!("      {}{}", s.size, rates(&s.fps, s.fps_range)));
    }
    if let Some(r) = f.steps {
        out.push(format!(
            "      {} to {} in steps of {}",
            r.min, r.max, r.step
        ));
    }
}

fn render_control(c: &ControlInfo) -> String {
    let kind = match c.kind {
        ControlKind::Other(n) => format!("type {n}"),
        k => serde_json::to_value(k)
            .ok()
            .and_then(|v| v.as_str().map(str::to_string))
            .unwrap_or_default(),
    };
    let value = c.value.map_or("-".to_string(), |v| v.to_string());
    let mut line = format!(
        "    {:#010x} {:<32} {kind} {}..{} step {} default {} = {value}",
        c.id, c.name, c.min, c.max, c.step, c.default
    );
    if c.read_only {
        line.push_str(" (read-only)");
    }
    if c.inactive {
        line.push_str(" (inactive)");
    }
    if !c.menu.is_empty() {
        let items: Vec<String> = c
            .menu
            .iter()
            .map(|m| format!("{}: {}", m.index, m.name))
            .collect();
        line.push_str(&format!(" [{}]", items.join(", ")));
    }
    line
}

/// The listing as text, one block per node; a line saying so when there is none.
pub fn render(list: &[CameraListing]) -> String {
    if list.is_empty() {
        return "no camera found (no /dev/video* device)\n".into();
    }
    let mut out = Vec::new();
    for l in list {
        let mut head = format!("{}:", l.path.display());
        if !l.card.is_empty() {
            head.push_str(&format!(" {} ({}, {})", l.card, l.driver, l.bus));
        }
        if !l.capture && l.error.is_none() {
            head.push_str(" — not a video capture node");
        }
        out.push(head);
        if let Some(e) = &l.error {
            out.push(format!("  cannot read it: {e}"));
        }
        if !l.formats.is_empty() {
            out.push("  formats:".into());
            for f in &l.formats {
                render_format(f, &mut out);
            }
        }
        if !l.controls.is_empty() {
            out.push("  controls (id, name, type, range, default = current):".into());
            out.extend(l.controls.iter().map(render_control));
        }
    }
    out.push(String::new());
    out.join("\n")
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::controls::{MenuEntry, cid};
    use crate::camera::format::SizeOffer;
    use crate::camera::pixels::FourCc;
    use crate::raster::ImageSize;

    pub(crate) fn sample() -> CameraListing {
        CameraListing {
            path: "/dev/video0".into(),
            driver: "uvcvideo".into(),
            card: "HD Webcam".into(),
            bus: "usb-0000:00:14.0-1".into(),
            capture: true,
            formats: vec![FormatOffer {
                fourcc: FourCc(*b"YUYV"),
                description: "YUYV 4:2:2".into(),
                sizes: vec![SizeOffer {
                    size: ImageSize::new(640, 480),
                    fps: vec![30.0, 7.5],
                    fps_range: false,
                }],
                steps: None,
            }],
            controls: vec![ControlInfo {
                id: cid::EXPOSURE_AUTO,
                name: "Auto Exposure".into(),
                kind: ControlKind::Menu,
                min: 0,
                max: 3,
                step: 1,
                default: 3,
                value: Some(3),
                read_only: false,
                inactive: false,
                menu: vec![
                    MenuEntry {
                        index: 1,
                        name: "Manual Mode".into(),
                    },
                    MenuEntry {
                        index: 3,
                        name: "Aperture Priority Mode".into(),
                    },
                ],
            }],
            error: None,
        }
    }

    #[test]
    fn text_lists_formats_sizes_rates_and_controls() {
        let text = render(&[sample()]);
        assert!(text.contains("/dev/video0: HD Webcam (uvcvideo"), "{text}");
        assert!(text.contains("YUYV \"YUYV 4:2:2\""), "{text}");
        assert!(text.contains("640x480 @ 30, 7.5 fps"), "{text}");
        assert!(text.contains("0x009a0901 Auto Exposure"), "{text}");
        assert!(text.contains("menu 0..3 step 1 default 3 = 3"), "{text}");
        assert!(text.contains("1: Manual Mode"), "{text}");
        assert_eq!(render(&[]), "no camera found (no /dev/video* device)\n");
    }

    #[test]
    fn json_names_formats_by_fourcc_and_sizes_by_width_and_height() {
        let v = serde_json::to_value([sample()]).unwrap();
        let f = &v[0]["formats"][0];
        assert_eq!(f["fourcc"], "YUYV");
        assert_eq!(f["sizes"][0]["width"], 640);
        assert_eq!(f["sizes"][0]["fps"][1], 7.5);
        assert_eq!(v[0]["controls"][0]["kind"], "menu");
        assert_eq!(v[0]["controls"][0]["value"], 3);
        assert!(v[0].get("error").is_none());
    }

    #[test]
    fn video_nodes_are_found_in_number_order() {
        let dir = tempfile::tempdir().unwrap();
        for name in ["video10", "video2", "video-cam", "videos", "vbi0", "video0"] {
            std::fs::write(dir.path().join(name), b"").unwrap();
        }
        std::os::unix::fs::symlink(dir.path().join("video0"), dir.path().join("video99")).unwrap();
        let names: Vec<String> = video_nodes(dir.path())
            .iter()
            .map(|p| p.file_name().unwrap().to_string_lossy().into_owned())
            .collect();
        assert_eq!(names, ["video0", "video2", "video10"]);
        assert!(video_nodes(&dir.path().join("none")).is_empty());
    }
}
