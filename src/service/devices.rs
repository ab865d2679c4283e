//! The devices the service drives, opened from `[rig]` by [`crate::rigs::open`] as `compend
//! calibrate` opens its own: the virtual rig (its projector and camera, a GPU for the pass),
//! real hardware (the projector window and a V4L2 camera), or the window rig (the projector
//! window watched by a virtual camera on its own clock, as a V4L2 camera is: the hardware path
//! without hardware).

use std::cell::RefCell;
use std::path::Path;
use std::rc::Rc;
use std::time::{Duration, Instant};

use crate::config::Config;
use crate::device::{DisplaySink, FrameSource};
use crate::error::{Error, Result};
use crate::gpu::GpuContext;
use crate::model::Model;
use crate::model::set::SetModel;
use crate::raster::{ImageSize, PrjImage};
use crate::rig::VirtualRig;
use crate::rig::scene::Scene;
use crate::rigs::{self, Given, Opened, RigClock};
use crate::window::ProjectorWindows;

/// A word for the operator when `model` was calibrated on another rig than `rig` (this
/// service's, [`crate::rigs::rig_name`]: `virtual:SCENE`, `window:SCENE`, `camera:DEVICE`): its geometry and
/// colours are another surface's. `None` for a model of this rig, or one trained offline (no
/// calibration record). The virtual rig's seed is not in the name, so a model of the same scene
/// with another seed is not told apart.
pub(super) fn other_rig(model: &crate::model::Model, rig: &str, seed: u64) -> Option<String> {
    let c = model.meta.calibration.as_ref()?;
    let advice = "recalibrate, or swap a model of this rig back";
    if c.rig != rig {
        return Some(format!(
            "warning: it was calibrated on {}, not on this rig ({rig}): its geometry and colours \
             are that surface's; {advice}",
            c.rig
        ));
    }
    // A simulated surface's texture follows the seed: another seed is another surface.
    let simulated = rig.starts_with("virtual:") || rig.starts_with("window:");
    match c.seed {
        Some(s) if simulated && s != seed => Some(format!(
            "warning: it was calibrated on {rig} with seed {s}, not this rig's seed {seed}: the \
             simulated surface's texture is another; {advice}"
        )),
        _ => None,
    }
}

/// The virtual rig: its projector and camera, the scene, and a GPU for the pass.
pub(super) struct VirtualDevices {
    pub(super) rig: VirtualRig,
    pub(super) scene: Scene,
    pub(super) ctx: GpuContext,
    /// The projector's bump, for a scene with drift.
    pub(super) bump: Option<Bump>,
}

/// A simulated projector that is bumped to its scene's drifted pose once, `[rig]
/// drift_after_s` after playback first starts (for trying monitoring and recalibration).
pub(super) struct Bump {
    rig: VirtualRig,
    /// When the projector moves, once armed.
    at: Option<Instant>,
    /// It moved: never again.
    moved: bool,
}

impl Bump {
    /// The bump of `rig`'s projector, when its `scene` has a drifted pose (a warning when
    /// `drift_after_s` asks for a bump it has not).
    fn of(rig: VirtualRig, scene: &Scene, drift_after_s: Option<f64>) -> Option<Self> {
        if scene.drift.is_none() {
            if drift_after_s.is_some() {
                tracing::warn!(
                    "[rig] drift_after_s: scene {:?} has no drift; the projector stays put",
                    scene.name
                );
            }
            return None;
        }
        Some(Self {
            rig,
            at: None,
            moved: false,
        })
    }

    /// For a playback starting now: the rig and when its projector moves, unless it moved
    /// already (armed at the first playback, `after_s` seconds on).
    pub(super) fn arm(&mut self, after_s: Option<f64>) -> Option<(VirtualRig, Instant)> {
        if self.moved {
            return None;
        }
        if self.at.is_none() {
            self.at = Some(Instant::now() + Duration::from_secs_f64(after_s?));
        }
        Some((self.rig.clone(), self.at?))
    }

    /// After a playback that was given the bump: `pending` still holds it when the projector
    /// did not move during the playback.
    pub(super) fn played(&mut self, pending: &Option<(VirtualRig, Instant)>) {
        if self.at.is_some() && pending.is_none() {
            self.moved = true;
        }
    }
}

/// The projector window and a camera that streams on its own clock: a V4L2 camera (real
/// hardware) or the window rig's virtual camera looking at the window's presented frames.
pub(super) struct Hardware {
    pub(super) win: crate::window::ProjectorWindow,
    pub(super) camera: Box<dyn FrameSource + Send>,
    /// What the camera is, for the log.
    pub(super) camera_name: String,
    /// The window rig's simulated projector bump, for a scene with drift.
    pub(super) bump: Option<Bump>,
}

/// A set of projectors seen by one camera: one output per projector, in the set's order.
pub(super) enum SetDevices {
    /// A set's scene on the virtual rig: its outputs and its camera (clones of one rig), and a
    /// GPU for the joint pass.
    Virtual {
        rig: VirtualRig,
        scene: Box<Scene>,
        ctx: GpuContext,
        /// The first projector's bump, for a scene with drift.
        bump: Option<Bump>,
    },
    /// One fullscreen window per projector's monitor on one GPU device, and a camera on its own
    /// clock (a V4L2 camera, or the window rig's virtual camera).
    Windows {
        windows: Rc<RefCell<ProjectorWindows>>,
        camera: Box<dyn FrameSource + Send>,
        /// What the camera is, for the log.
        camera_name: String,
    },
}

impl SetDevices {
    /// How many projectors.
    pub(super) fn len(&self) -> usize {
        match self {
            SetDevices::Virtual { rig, .. } => rig.outputs(),
            SetDevices::Windows { windows, .. } => windows.borrow().sizes().len(),
        }
    }

    /// Each projector's output as a display of its own, in the set's order.
    pub(super) fn displays(&self) -> Result<Vec<Box<dyn DisplaySink>>> {
        Ok(match self {
            SetDevices::Virtual { rig, .. } => (0..rig.outputs())
                .map(|k| Ok(Box::new(rig.output(k)?) as Box<dyn DisplaySink>))
                .collect::<Result<Vec<_>>>()?,
            SetDevices::Windows { windows, .. } => ProjectorWindows::outputs(windows)
                .into_iter()
                .map(|o| Box::new(o) as Box<dyn DisplaySink>)
                .collect(),
        })
    }

    /// What each output is, in the set's order: the monitor's name, or the virtual rig's
    /// projector.
    pub(super) fn names(&self) -> Vec<String> {
        match self {
            SetDevices::Virtual { rig, .. } => (1..=rig.outputs())
                .map(|k| format!("virtual projector {k}"))
                .collect(),
            SetDevices::Windows { windows, .. } => windows.borrow().monitors(),
        }
    }

    /// Shows `image` on every projector, stretched to each one's size.
    pub(super) fn show_all(&self, image: &PrjImage) -> Result<()> {
        for mut d in self.displays()? {
            let size = d.size();
            if size == image.size() {
                d.show(image)?;
            } else {
                d.show(&crate::resize::resize_bilinear(
                    image,
                    size.width,
                    size.height,
                ))?;
            }
        }
        Ok(())
    }

    /// The camera that sees the set.
    pub(super) fn camera(&mut self) -> &mut dyn FrameSource {
        match self {
            SetDevices::Virtual { rig, .. } => rig,
            SetDevices::Windows { camera, .. } => &mut **camera,
        }
    }

    /// Each projector's size (projector pixels), in the set's order.
    pub(super) fn sizes(&self) -> Vec<ImageSize> {
        match self {
            SetDevices::Virtual { scene, .. } => {
                scene.projectors().iter().map(|p| p.size()).collect()
            }
            SetDevices::Windows { windows, .. } => windows.borrow().sizes(),
        }
    }
}

pub(super) enum Devices {
    Virtual(Box<VirtualDevices>),
    Hardware(Box<Hardware>),
    Set(Box<SetDevices>),
}

impl Devices {
    pub(super) fn open(config: &Config) -> Result<Self> {
        let r = &config.rig;
        Ok(match rigs::open(r, RigClock::Simulated, Given::File)? {
            Opened::Virtual { rig, scene } if rig.outputs() > 1 => {
                let bump = Bump::of(rig.clone(), &scene, r.drift_after_s);
                let ctx = GpuContext::new()?;
                Devices::Set(Box::new(SetDevices::Virtual {
                    rig,
                    scene: Box::new(scene),
                    ctx,
                    bump,
                }))
            }
            Opened::Virtual { rig, scene } => {
                let bump = Bump::of(rig.clone(), &scene, r.drift_after_s);
                let ctx = GpuContext::new()?;
                Devices::Virtual(Box::new(VirtualDevices {
                    rig,
                    scene,
                    ctx,
                    bump,
                }))
            }
            Opened::Window { win, camera, scene } => {
                let bump = Bump::of(camera.rig(), &scene, r.drift_after_s);
                let l = &scene.latency;
                Devices::Hardware(Box::new(Hardware {
                    win,
                    camera: Box::new(camera),
                    camera_name: format!(
                        "virtual, scene {:?} at {} fps, {} frames of delay",
                        scene.name, l.fps, l.delay_frames
                    ),
                    bump,
                }))
            }
            Opened::WindowSet {
                windows,
                camera,
                scene,
            } => {
                let l = &scene.latency;
                Devices::Set(Box::new(SetDevices::Windows {
                    windows,
                    camera: Box::new(camera),
                    camera_name: format!(
                        "virtual, scene {:?} at {} fps, {} frames of delay",
                        scene.name, l.fps, l.delay_frames
                    ),
                }))
            }
            #[cfg(target_os = "linux")]
            Opened::CameraSet {
                windows,
                camera,
                device,
                controls,
            } => {
                for line in controls {
                    tracing::info!("camera {}: {line}", device.display());
                }
                Devices::Set(Box::new(SetDevices::Windows {
                    windows,
                    camera: Box::new(camera),
                    camera_name: device.display().to_string(),
                }))
            }
            #[cfg(target_os = "linux")]
            Opened::Camera {
                win,
                camera,
                device,
                controls,
            } => {
                for line in controls {
                    tracing::info!("camera {}: {line}", device.display());
                }
                Devices::Hardware(Box::new(Hardware {
                    win,
                    camera: Box::new(camera),
                    camera_name: device.display().to_string(),
                    bump: None,
                }))
            }
        })
    }

    /// The projector's size (projector pixels; a set's first projector's).
    pub(super) fn display_size(&self) -> ImageSize {
        match self {
            Devices::Virtual(v) => v.scene.projector.size(),
            Devices::Hardware(h) => DisplaySink::size(&h.win),
            Devices::Set(s) => s.sizes().first().copied().unwrap_or(ImageSize::new(0, 0)),
        }
    }

    /// The timer of a climb's live pass on the playback GPU, at `refresh_hz` (`[calibration]
    /// refresh_hz`), else at the projector window's rate; the virtual rig's climbs only when it
    /// is set. `None`: not weighed (0, or a virtual rig without it).
    pub(super) fn live_pass(
        &self,
        refresh_hz: Option<f64>,
    ) -> Option<std::sync::Arc<dyn crate::fit::LivePass>> {
        let (ctx, hz) = match self {
            Devices::Virtual(v) => (&v.ctx, refresh_hz?),
            Devices::Hardware(h) => (h.win.context(), refresh_hz.unwrap_or(h.win.refresh_hz())),
            // A set climbs no rung: it is compensated jointly from `linear` models.
            Devices::Set(_) => return None,
        };
        let pass = crate::gpu::live::GpuLivePass::new(ctx.clone(), hz).ok()?;
        Some(std::sync::Arc::new(pass))
    }

    pub(super) fn camera_size(&self) -> ImageSize {
        match self {
            Devices::Virtual(v) => v.scene.camera.size(),
            Devices::Hardware(h) => FrameSource::size(&h.camera),
            Devices::Set(s) => match &**s {
                SetDevices::Virtual { scene, .. } => scene.camera.size(),
                SetDevices::Windows { camera, .. } => FrameSource::size(camera),
            },
        }
    }

    pub(super) fn describe(&self) -> String {
        match self {
            Devices::Virtual(v) => format!(
                "virtual rig {:?} (projector {}, camera {} at {} fps, {} frames of delay); GPU: {}",
                v.scene.name,
                v.scene.projector.size(),
                v.scene.camera.size(),
                v.scene.latency.fps,
                v.scene.latency.delay_frames,
                v.ctx.describe()
            ),
            Devices::Hardware(h) => format!(
                "projector window {} at {:.1} Hz, camera {} ({}); GPU: {}",
                DisplaySink::size(&h.win),
                h.win.refresh_hz(),
                h.camera_name,
                FrameSource::size(&h.camera),
                h.win.context().describe()
            ),
            Devices::Set(s) => {
                let outputs: Vec<String> = s
                    .names()
                    .iter()
                    .zip(s.sizes())
                    .map(|(n, size)| format!("{n} ({size})"))
                    .collect();
                match &**s {
                    SetDevices::Virtual { scene, ctx, .. } => format!(
                        "virtual rig {:?}, a set of {} projectors: {}; camera {} at {} fps, {} \
                         frames of delay; GPU: {}",
                        scene.name,
                        outputs.len(),
                        outputs.join(", "),
                        scene.camera.size(),
                        scene.latency.fps,
                        scene.latency.delay_frames,
                        ctx.describe()
                    ),
                    SetDevices::Windows {
                        windows,
                        camera,
                        camera_name,
                    } => format!(
                        "a set of {} projector windows at {:.1} Hz: {}; camera {camera_name} \
                         ({}); GPU: {}",
                        outputs.len(),
                        windows.borrow().refresh_hz(),
                        outputs.join(", "),
                        FrameSource::size(camera),
                        windows.borrow().context().describe()
                    ),
                }
            }
        }
    }

    /// Shows `image` on the projector (paused, stopping: black; the setup view's pattern), on
    /// each of a set's projectors stretched to its size.
    pub(super) fn show_everywhere(&mut self, image: &PrjImage) -> Result<()> {
        match self {
            Devices::Virtual(v) => v.rig.show(image),
            Devices::Hardware(h) => h.win.show(image),
            Devices::Set(s) => s.show_all(image),
        }
    }

    /// Shows black (paused, stopping).
    pub(super) fn black(&mut self) -> Result<()> {
        let black = PrjImage::new(self.display_size().width, self.display_size().height);
        self.show_everywhere(&black)
    }
}

/// Loads the model directory `path` for a rig whose camera gives `camera`-sized images; a model
/// for another camera size is an input error naming both.
pub(super) fn load_model(path: &Path, camera: ImageSize) -> Result<Model> {
    let model = Model::load(path)?;
    if model.camera_size() != camera {
        return Err(Error::Input(format!(
            "{}: the model is for {} camera images, this rig's camera gives {camera}",
            path.display(),
            model.camera_size()
        )));
    }
    Ok(model)
}

/// Loads the set's model directory `path` for a set of `projectors` seen by a camera of
/// `camera` pixels: one projector's model, another number of projectors, another camera size,
/// a set never calibrated as a whole or not compensable jointly is an input error naming it.
pub(super) fn load_set_model(
    path: &Path,
    projectors: usize,
    camera: ImageSize,
) -> Result<SetModel> {
    if !SetModel::is_set(path) && path.join(crate::model::store::META_FILE).is_file() {
        return Err(Error::Input(format!(
            "{}: one projector's model; this rig is a set of {projectors} projectors: calibrate \
             the set (compend recalibrate) or point [paths] model at a set's model",
            path.display()
        )));
    }
    let model = SetModel::load(path)?;
    if model.models.len() != projectors {
        return Err(Error::Input(format!(
            "{}: the model is for a set of {} projectors, this rig has {projectors}",
            path.display(),
            model.models.len()
        )));
    }
    if model.meta.camera_size != camera {
        return Err(Error::Input(format!(
            "{}: the model is for {} camera images, this rig's camera gives {camera}",
            path.display(),
            model.meta.camera_size
        )));
    }
    if model.meta.calibration.is_none() {
        return Err(Error::Input(format!(
            "{}: no calibration record in set.json (where the set's picture goes, in which \
             range): calibrate the set (compend recalibrate)",
            path.display()
        )));
    }
    model.joint()?;
    Ok(model)
}

/// Sets the camera to the exposure `model` was calibrated at (a calibrated model saw the
/// camera there; monitoring compares against that); nothing for an uncalibrated model. The
/// caller makes sure the model was calibrated with this camera.
pub(super) fn match_exposure<C: FrameSource + ?Sized>(camera: &mut C, model: &Model) -> Result<()> {
    if let Some(e) = model
        .meta
        .calibration
        .as_ref()
        .and_then(|c| c.exposure.as_ref())
    {
        camera.set_exposure(e.chosen)?;
    }
    Ok(())
}
