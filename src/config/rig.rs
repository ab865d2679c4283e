//! `[rig]`: the devices compend drives.

use std::path::PathBuf;

use serde::Serialize;

use super::read::{Table, Walker};
use crate::raster::ImageSize;

/// Where the projector and the camera come from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum RigKind {
    /// The built-in virtual rig (simulated projector, surface and camera).
    Virtual,
    /// The projector window watched by a virtual camera (testing the display path).
    Window,
    /// The projector window and a V4L2 camera: real hardware.
    Camera,
}

/// `[rig]`: the devices.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct RigConfig {
    pub kind: RigKind,
    /// `virtual`/`window`: a built-in scene or a scene JSON file.
    pub scene: String,
    /// Seed of the sampling images (and of the virtual rig's texture and noise).
    pub seed: u64,
    /// `camera`: the V4L2 device (a /dev/v4l/by-id/ path survives re-plugging).
    pub camera: Option<PathBuf>,
    /// `camera`: the capture size; `virtual`/`window`: the virtual camera's resolution.
    pub camera_size: Option<ImageSize>,
    /// `virtual`: the projector resolution (the window's is its monitor's).
    pub projector: Option<ImageSize>,
    /// `window`/`camera`: the projector's monitor, by name or index.
    pub monitor: Option<String>,
    /// `virtual`: the display refresh rate playback is paced at, Hz.
    pub fps: f64,
    /// `virtual`/`window`: the virtual camera's frame rate, Hz (default: the scene's).
    pub camera_fps: Option<f64>,
    /// `virtual`/`window`: projector-to-camera delay, ms (default: the scene's).
    pub latency_ms: Option<f64>,
    /// `virtual`/`window`, scenes with drift: seconds after playback first starts at which the
    /// simulated projector is moved to the scene's drifted pose (a bump, for testing monitoring
    /// and recalibration).
    pub drift_after_s: Option<f64>,
    /// `[[projector]]`: a set of projectors, one section per projector in the set's order
    /// (empty: one projector, or the virtual scene's set). Their monitors are also in
    /// `monitor`, comma-separated, as a set's monitors are given on the command line.
    pub projectors: Vec<ProjectorConfig>,
}

/// `[[projector]]`: one projector of a set.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct ProjectorConfig {
    /// `window`/`camera`: this projector's monitor, by name or index.
    pub monitor: Option<String>,
    /// This projector's compensated frames to other software as well (`file:PATH`, each
    /// playback to `NAME-NNNN.EXT` beside it, or `gst:PIPELINE`): given for every projector of
    /// the set or for none.
    #[serde(serialize_with = "super::output::output_or_none")]
    pub to: Option<crate::output::OutputSpec>,
}

impl ProjectorConfig {
    fn read<'t>(w: &mut Walker<'t>, t: &mut Table<'t>) -> Self {
        ProjectorConfig {
            monitor: w.get(t, "monitor"),
            to: w.parsed_with(t, "to", |s| {
                crate::output::OutputSpec::parse(s).map_err(|e| e.to_string())
            }),
        }
    }

    /// Reads the `[[projector]]` sections of `root` into `rig`, checked against its kind: a
    /// window or camera rig needs each projector's monitor (then `rig.monitor` lists them,
    /// comma-separated), the virtual rig has its own outputs.
    pub(super) fn read_into<'t>(w: &mut Walker<'t>, root: &mut Table<'t>, rig: &mut RigConfig) {
        let sections = w.tables(root, "projector");
        if sections.is_empty() {
            // The keys a section takes, for the list of known keys.
            let mut none = Table {
                name: "projector",
                entries: Vec::new(),
            };
            Self::read(w, &mut none);
            return;
        }
        let mut monitors = Vec::new();
        for (k, (at, mut t)) in sections.into_iter().enumerate() {
            let span = super::read::span_of(&t, "monitor");
            let p = Self::read(w, &mut t);
            w.finish(t);
            match (&p.monitor, rig.kind) {
                (Some(_), RigKind::Virtual) => w.error(
                    span,
                    format!(
                        "[[projector]] {} monitor: the virtual rig has its own outputs (one per \
                         projector of its scene); leave monitor out",
                        k + 1
                    ),
                ),
                (Some(m), _) if m.trim().is_empty() || m.contains(',') => w.error(
                    span,
                    format!(
                        "[[projector]] {} monitor: {m:?} is not one monitor's name or index",
                        k + 1
                    ),
                ),
                (Some(m), _) => monitors.push(m.trim().to_string()),
                (None, RigKind::Virtual) => {}
                (None, _) => w.error(
                    at,
                    format!(
                        "[[projector]] {}: a {} rig needs each projector's monitor (monitor = \
                         \"HDMI-1\")",
                        k + 1,
                        if rig.kind == RigKind::Camera {
                            "camera"
                        } else {
                            "window"
                        }
                    ),
                ),
            }
            rig.projectors.push(p);
        }
        let outputs = rig.projectors.iter().filter(|p| p.to.is_some()).count();
        if outputs > 0 && outputs < rig.projectors.len() {
            w.errors.push((
                w.line(0),
                format!(
                    "[[projector]] to: given for {outputs} of {} projectors; give each \
                     projector's output, or none",
                    rig.projectors.len()
                ),
            ));
        }
        if rig.kind != RigKind::Virtual && monitors.len() == rig.projectors.len() {
            if let Some(m) = &rig.monitor {
                w.errors.push((
                    w.line(0),
                    format!(
                        "[rig] monitor = {m:?} and [[projector]] sections both name monitors: \
                         name each projector's in its own [[projector]] section"
                    ),
                ));
            }
            rig.monitor = Some(monitors.join(","));
        }
    }
}

impl Default for RigConfig {
    /// The virtual rig on the `curved` scene, seed 0, paced at 60 Hz; the rest from the scene.
    fn default() -> Self {
        RigConfig {
            kind: RigKind::Virtual,
            scene: "curved".to_string(),
            seed: 0,
            camera: None,
            camera_size: None,
            projector: None,
            monitor: None,
            fps: 60.0,
            camera_fps: None,
            latency_ms: None,
            drift_after_s: None,
            projectors: Vec::new(),
        }
    }
}

impl RigConfig {
    pub(super) fn read<'t>(w: &mut Walker<'t>, t: &mut Table<'t>) -> Self {
        let kind = w.choice(
            t,
            "kind",
            RigKind::Virtual,
            &[
                ("virtual", RigKind::Virtual),
                ("window", RigKind::Window),
                ("camera", RigKind::Camera),
            ],
        );
        let rig = RigConfig {
            kind,
            scene: w.get(t, "scene").unwrap_or_else(|| "curved".to_string()),
            seed: w.get(t, "seed").unwrap_or(0),
            camera: w.get(t, "camera"),
            camera_size: w.size(t, "camera_size", false),
            projector: w.size(t, "projector", false),
            monitor: w.get(t, "monitor"),
            fps: w.positive(t, "fps", 60.0),
            camera_fps: w.optional_positive(t, "camera_fps"),
            latency_ms: w.optional_non_negative(t, "latency_ms"),
            drift_after_s: w.optional_non_negative(t, "drift_after_s"),
            projectors: Vec::new(),
        };
        if kind == RigKind::Camera && rig.camera.is_none() {
            w.errors.push((
                w.line(0),
                "[rig] kind = \"camera\" needs `camera`, the V4L2 device (e.g. /dev/video0)".into(),
            ));
        }
        rig
    }
}
