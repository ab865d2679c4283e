//! The rig compend drives, opened from a resolved `[rig]` ([`RigConfig`]): the virtual rig (a
//! simulated projector and camera), the window rig (the projector window watched by a virtual
//! camera on its own clock), or a projector window with a V4L2 camera. A set of projectors (a
//! set's scene, or several monitors named in `monitor`, comma-separated) gets one window per
//! projector's monitor ([`ProjectorWindows`]). `compend calibrate` (from
//! its flags or its `--config`) and `compend serve` open their rig with [`open`] and build their
//! calibration's [`Options`] with [`calibration_options`], so the two cannot open a rig or
//! calibrate it differently.

use std::cell::RefCell;
use std::path::PathBuf;
use std::rc::Rc;
use std::sync::Arc;
use std::sync::atomic::AtomicBool;

use crate::calibrate::{self, Options, PatternSet, SyncSettings};
use crate::config::{CalibrationConfig, RigConfig, RigKind};
use crate::device::DisplaySink;
use crate::error::{Error, Result};
use crate::model::{Method, MethodChoice};
use crate::raster::ImageSize;
use crate::rig::VirtualRig;
use crate::rig::scene::{self, Scene};
use crate::rig::window_camera::WindowCamera;
use crate::window::{ProjectorWindow, ProjectorWindows};

/// Where a rig's settings were written, so that an error names what the person wrote: a flag
/// (`--projector 640x480`) or a key of the configuration (`[rig] projector = "640x480"`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Given {
    Flags,
    File,
}

impl Given {
    /// The `[rig]` key `key` with `value`, as the person wrote it.
    fn name(self, key: &str, value: &str) -> String {
        match self {
            Given::Flags => format!("--{} {value}", key.replace('_', "-")),
            Given::File => format!("[rig] {key} = {value:?}"),
        }
    }
}

/// How a virtual camera keeps time (`calibrate --rig-clock`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum RigClock {
    /// Frames no faster than the camera's frame rate, as a real camera.
    Wall,
    /// Frames as fast as they are simulated.
    Simulated,
}

/// An opened rig: a display that shows projector frames and a camera that sees the surface.
// Opened once per run and taken apart at once: boxing the large variants would buy nothing.
#[allow(clippy::large_enum_variant)]
pub enum Opened {
    /// The virtual rig: one value is both the projector and the camera (clone it for each).
    Virtual { rig: VirtualRig, scene: Scene },
    /// The projector window, watched by a virtual camera on the scene's surface.
    Window {
        win: ProjectorWindow,
        camera: WindowCamera,
        scene: Scene,
    },
    /// The projector window and a V4L2 camera, its controls locked for calibration.
    #[cfg(target_os = "linux")]
    Camera {
        win: ProjectorWindow,
        camera: crate::camera::V4l2Camera,
        device: PathBuf,
        /// What locking the camera's controls did, a line each, for the log.
        controls: Vec<String>,
    },
    /// A set's windows (one per projector's monitor), watched by a virtual camera on the set's
    /// scene.
    WindowSet {
        windows: Rc<RefCell<ProjectorWindows>>,
        camera: WindowCamera,
        scene: Scene,
    },
    /// A set's windows and a V4L2 camera, its controls locked for calibration.
    #[cfg(target_os = "linux")]
    CameraSet {
        windows: Rc<RefCell<ProjectorWindows>>,
        camera: crate::camera::V4l2Camera,
        device: PathBuf,
        controls: Vec<String>,
    },
}

/// What the rig is, in the words a calibration record and the service's status use:
/// `virtual:SCENE`, `window:SCENE` or `camera:DEVICE`.
pub fn rig_name(r: &RigConfig) -> String {
    match r.kind {
        RigKind::Virtual => format!("virtual:{}", r.scene),
        RigKind::Window => format!("window:{}", r.scene),
        RigKind::Camera => format!(
            "camera:{}",
            r.camera
                .as_deref()
                .unwrap_or(std::path::Path::new("?"))
                .display()
        ),
    }
}

/// The scene of a virtual or window rig: `[rig] scene` with the virtual camera at `[rig]
/// camera_size` (else the scene's), the projector at `projector` (the window's) or `[rig]
/// projector` (else the scene's), and `[rig]`'s camera timing.
pub fn scene(r: &RigConfig, projector: Option<ImageSize>) -> Result<Scene> {
    let scene = scene::load(&r.scene)?;
    let camera = r.camera_size.unwrap_or(scene.camera.size());
    let projector = projector.or(r.projector).unwrap_or(scene.projector.size());
    let scene = scene
        .with_resolution(camera, projector)
        .with_timing(r.camera_fps, r.latency_ms);
    scene.validate()?;
    Ok(scene)
}

/// Opens the rig `r` describes; `clock` times the virtual rig's camera, `given` says where `r`
/// was written, for errors. A V4L2 camera is opened and locked before the window opens, so a
/// missing or wrong device fails before anything is shown.
pub fn open(r: &RigConfig, clock: RigClock, given: Given) -> Result<Opened> {
    match r.kind {
        RigKind::Virtual => {
            let scene = scene(r, None)?;
            check_sections(r, &scene)?;
            let rig = VirtualRig::new(&scene, r.seed)?;
            let rig = match clock {
                RigClock::Wall => rig.on_wall_clock(),
                RigClock::Simulated => rig,
            };
            Ok(Opened::Virtual { rig, scene })
        }
        RigKind::Window => {
            let named = scene::load(&r.scene)?;
            check_sections(r, &named)?;
            if !named.more_projectors.is_empty() {
                return open_window_set(r, given, named.projectors().len());
            }
            let mut win = ProjectorWindow::open(r.monitor.as_deref())?;
            let size = DisplaySink::size(&win);
            if let Some(p) = r.projector
                && p != size
            {
                return Err(Error::Input(format!(
                    "{}: the projector window on {} is {size}; leave it out or pick the monitor \
                     of that size",
                    given.name("projector", &p.to_string()),
                    r.monitor.as_deref().unwrap_or("the primary monitor")
                )));
            }
            let scene = scene(r, Some(size))?;
            let camera = win.watched_by(&scene, r.seed)?;
            Ok(Opened::Window { win, camera, scene })
        }
        RigKind::Camera => open_camera(r, given),
    }
}

/// `[[projector]]` sections, where given, are as many as the simulated scene's projectors.
pub fn check_sections(r: &RigConfig, scene: &Scene) -> Result<()> {
    let (given, has) = (r.projectors.len(), scene.projectors().len());
    if given > 0 && given != has {
        return Err(Error::Input(format!(
            "[[projector]]: {given} section(s), and scene {:?} has {has} projector(s): one \
             section per projector of the scene, or none",
            scene.name
        )));
    }
    Ok(())
}

/// The monitors `[rig] monitor` names, comma-separated (one per projector of a set).
fn monitor_list(r: &RigConfig) -> Vec<String> {
    r.monitor
        .as_deref()
        .map(|m| m.split(',').map(|s| s.trim().to_string()).collect())
        .unwrap_or_default()
}

/// A set's windows on the monitors `r` names, one per projector of `projectors`, checked: as
/// many as projectors, all of one size (and that of `[rig] projector` when given).
fn open_set_windows(
    r: &RigConfig,
    given: Given,
    projectors: usize,
) -> Result<(Rc<RefCell<ProjectorWindows>>, ImageSize)> {
    let monitors = monitor_list(r);
    if monitors.len() != projectors || monitors.iter().any(String::is_empty) {
        let named = match r.monitor.as_deref() {
            Some(m) => given.name("monitor", m),
            None => match given {
                Given::Flags => "--monitor is not given".to_string(),
                Given::File => "[rig] monitor is not set".to_string(),
            },
        };
        return Err(Error::Input(format!(
            "{named}: a set of {projectors} projectors needs one monitor per projector, in the \
             set's order, comma-separated ({})",
            given.name("monitor", "HDMI-1,HDMI-2")
        )));
    }
    let names: Vec<&str> = monitors.iter().map(String::as_str).collect();
    let windows = ProjectorWindows::open(&names)?;
    let sizes = windows.sizes();
    if sizes.iter().any(|s| *s != sizes[0]) {
        let list: Vec<String> = names
            .iter()
            .zip(&sizes)
            .map(|(m, s)| format!("{m} is {s}"))
            .collect();
        return Err(Error::Input(format!(
            "{}: a set's monitors must be of one size ({}); set them alike (xrandr --mode)",
            given.name("monitor", r.monitor.as_deref().unwrap_or("")),
            list.join(", ")
        )));
    }
    if let Some(p) = r.projector
        && p != sizes[0]
    {
        return Err(Error::Input(format!(
            "{}: the set's windows are {}; leave it out or pick monitors of that size",
            given.name("projector", &p.to_string()),
            sizes[0]
        )));
    }
    Ok((Rc::new(RefCell::new(windows)), sizes[0]))
}

/// A set's scene on windows, one per projector's monitor, watched by a virtual camera.
fn open_window_set(r: &RigConfig, given: Given, projectors: usize) -> Result<Opened> {
    let (windows, size) = open_set_windows(r, given, projectors)?;
    let scene = scene(r, Some(size))?;
    let camera = windows.borrow_mut().watched_by(&scene, r.seed)?;
    Ok(Opened::WindowSet {
        windows,
        camera,
        scene,
    })
}

#[cfg(target_os = "linux")]
fn open_camera(r: &RigConfig, given: Given) -> Result<Opened> {
    let device = r.camera.clone().unwrap_or_default();
    let mut camera = crate::camera::V4l2Camera::open(&device, r.camera_size)?;
    let controls = camera
        .lock_for_calibration(&crate::camera::LockSettings::default())?
        .lines();
    let monitors = monitor_list(r);
    if monitors.len() > 1 {
        let (windows, _) = open_set_windows(r, given, monitors.len())?;
        return Ok(Opened::CameraSet {
            windows,
            camera,
            device,
            controls,
        });
    }
    let win = ProjectorWindow::open(r.monitor.as_deref())?;
    Ok(Opened::Camera {
        win,
        camera,
        device,
        controls,
    })
}

#[cfg(not(target_os = "linux"))]
fn open_camera(r: &RigConfig, given: Given) -> Result<Opened> {
    let device = r.camera.as_deref().unwrap_or(std::path::Path::new(""));
    Err(Error::Input(format!(
        "{}: V4L2 cameras exist on Linux only",
        given.name("camera", &device.display().to_string())
    )))
}

/// A calibration's options from the rig `r` and the settings `c` (`[calibration]`, or
/// `calibrate`'s flags over it), for a projector of `projector` pixels. `refit`: a refit from
/// this many sampling pairs (`[monitoring] refit_ntrain`): the `linear` rung, verified on `c`'s
/// verification images. `live` times `auto`'s climb, `cancel` stops the calibration between
/// captures.
pub fn calibration_options(
    r: &RigConfig,
    c: &CalibrationConfig,
    refit: Option<usize>,
    projector: ImageSize,
    live: Option<Arc<dyn crate::fit::LivePass>>,
    cancel: Option<Arc<AtomicBool>>,
) -> Options {
    let (count, ntest, method) = match refit {
        Some(n) => (
            calibrate::SamplingCount::Count(n),
            c.verify,
            MethodChoice::Rung(Method::Linear),
        ),
        None => (c.ntrain, c.ntest, c.method),
    };
    let ntrain = count.most();
    Options {
        patterns: PatternSet {
            seed: r.seed,
            ntrain,
            ntest,
            network: c.network,
            projector,
            gray_level: crate::patterns::DEFAULT_GRAY_LEVEL,
        },
        method,
        fit_seed: 0,
        sync: SyncSettings {
            average: c.average,
            ..SyncSettings::default()
        },
        verify_images: c.verify,
        required_gain_db: c.min_gain_db,
        climb_gain_db: c.climb_gain_db,
        iters: c.climb_iters.filter(|_| method == MethodChoice::Auto),
        device: c.device,
        loop_images: calibrate::loop_images(method, ntrain, c.loop_images),
        rounds: calibrate::rounds::rounds_for(count, c.loop_images),
        live: live.filter(|_| method == MethodChoice::Auto),
        rig: rig_name(r),
        cancel,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::Config;
    use crate::fit::TrainDevice;

    #[test]
    fn an_error_names_the_rig_setting_as_it_was_written() {
        assert_eq!(
            Given::Flags.name("projector", "640x480"),
            "--projector 640x480"
        );
        assert_eq!(
            Given::Flags.name("camera_size", "320x240"),
            "--camera-size 320x240"
        );
        assert_eq!(
            Given::File.name("projector", "640x480"),
            "[rig] projector = \"640x480\""
        );
    }

    /// A timer that times nothing.
    #[derive(Debug)]
    struct NoPass;

    impl crate::fit::LivePass for NoPass {
        fn cost(&self, _: &crate::fit::PassShape) -> Result<crate::fit::LiveCost> {
            Err(Error::Failed("not timed".into()))
        }
    }

    #[test]
    fn a_calibration_takes_the_configured_method_and_device() {
        let mut config = Config::defaults();
        config.calibration.method = MethodChoice::Auto;
        config.calibration.device = TrainDevice::Cuda(1);
        config.calibration.climb_iters = Some(300);
        let projector = ImageSize::new(800, 600);
        let live: Arc<dyn crate::fit::LivePass> = Arc::new(NoPass);
        let o = calibration_options(
            &config.rig,
            &config.calibration,
            None,
            projector,
            Some(live.clone()),
            None,
        );
        assert_eq!(o.method, MethodChoice::Auto);
        // `auto` weighs its climb with the playback GPU's timer.
        assert!(o.live.is_some());
        assert_eq!(o.device, TrainDevice::Cuda(1));
        assert_eq!(o.iters, Some(300));
        assert_eq!(o.patterns.projector, projector);
        assert_eq!(o.patterns.ntrain, config.calibration.ntrain.most());
        // A drift refit fits `linear` on a handful of images, whatever the method.
        let refit = Some(config.monitoring.refit_ntrain);
        let o = calibration_options(
            &config.rig,
            &config.calibration,
            refit,
            projector,
            Some(live),
            None,
        );
        assert_eq!(o.method, MethodChoice::Rung(Method::Linear));
        assert!(o.live.is_none());
        assert_eq!(o.patterns.ntrain, config.monitoring.refit_ntrain);
        assert_eq!(o.iters, None);
    }
}
