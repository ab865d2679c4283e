//! Scene descriptions: every parameter of a simulated projector-camera setup, as plain serde
//! structs (so a scene can be written to and read from JSON or TOML), and the built-in scenes
//! ([`BUILTIN`], [`builtin`], [`load`]: the table of named scenes and loading a scene file).
//!
//! World coordinates are metres in the camera's frame of reference when the camera has the
//! identity pose: x to the right, y down, z forward (away from the camera, towards the surface).
//! Light quantities are linear and relative: a projector at full white with the identity
//! primaries emits 1.0 per channel, which a white (albedo 1) frontal surface at the reference
//! distance reflects as radiance 1.0.

use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::raster::ImageSize;

mod builtins;

pub use builtins::{BUILTIN, SETS, builtin, load};

/// A complete scene. Resolutions are part of it ([`Scene::with_resolution`] rescales every
/// pixel-valued parameter so the physical scene stays the same).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Scene {
    /// Short identifier, kebab-case (e.g. `white-plane`).
    pub name: String,
    /// One sentence: what the scene tests.
    pub summary: String,
    pub camera: CameraModel,
    pub projector: ProjectorModel,
    pub surface: Surface,
    pub albedo: Albedo,
    #[serde(default)]
    pub ambient: Ambient,
    /// Highlight of the projector's own light (moves with nothing, scales with the projection).
    #[serde(default)]
    pub specular: Option<Specular>,
    /// Static reflection of a room light in a glossy or glass surface (independent of the
    /// projection).
    #[serde(default)]
    pub glare: Option<Glare>,
    /// One bounce of projected light between parts of the surface (concave shapes).
    #[serde(default)]
    pub interreflection: Option<Interreflection>,
    /// Light that enters the surface and re-emerges elsewhere (translucent materials).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub subsurface: Option<Subsurface>,
    #[serde(default)]
    pub latency: Latency,
    /// How the projector moves after calibration (the drift scene); `None`: it stays put.
    #[serde(default)]
    pub drift: Option<Drift>,
    /// More projectors on the same surface, seen by the same camera (a set: tiled side by
    /// side, or stacked for brightness); `projector` is the first. Each lights the surface on
    /// its own and the camera sees the sum of their light ([`crate::rig::SetSimulator`]).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub more_projectors: Vec<ProjectorModel>,
}

/// Position and orientation of a camera or projector.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Pose {
    /// Optical centre in world metres.
    pub position: [f64; 3],
    /// [yaw, pitch, roll] in degrees, applied as R = Ry(yaw)·Rx(pitch)·Rz(roll) (device to
    /// world). Positive yaw turns the optical axis towards +x (right), positive pitch towards
    /// -y (up), positive roll turns the image clockwise as seen by the device.
    pub rotation_deg: [f64; 3],
}

impl Pose {
    /// The identity pose at the world origin.
    pub fn origin() -> Self {
        Pose {
            position: [0.0; 3],
            rotation_deg: [0.0; 3],
        }
    }

    /// A device at `position` whose optical axis points at `target`, with `roll_deg`. Angles
    /// are rounded to 1e-4 degrees so descriptions stay readable (and exact through JSON).
    pub fn looking_at(position: [f64; 3], target: [f64; 3], roll_deg: f64) -> Self {
        let d = [
            target[0] - position[0],
            target[1] - position[1],
            target[2] - position[2],
        ];
        let yaw = d[0].atan2(d[2]);
        let pitch = (-d[1]).atan2((d[0] * d[0] + d[2] * d[2]).sqrt());
        Pose {
            position,
            rotation_deg: [yaw.to_degrees(), pitch.to_degrees(), roll_deg]
                .map(|a| (a * 1e4).round() / 1e4),
        }
    }
}

/// Camera: pinhole optics and the sensor pipeline (colour mixing, exposure, vignetting, noise,
/// response curve, 8-bit quantisation and clipping).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraModel {
    /// Frame size in camera pixels.
    pub width: usize,
    pub height: usize,
    /// Horizontal field of view in degrees (square pixels, principal point at the centre).
    pub hfov_deg: f64,
    pub pose: Pose,
    /// Sensor colour mixing: sensor RGB = mixing · scene radiance RGB (rows = sensor channels).
    /// Entries must be non-negative.
    pub mixing: [[f64; 3]; 3],
    /// Linear gain from radiance to sensor signal (1.0 = full scale at radiance 1).
    pub exposure: f64,
    /// Response curve: encoded value = signal^(1/gamma) after clipping to \[0,1\].
    pub gamma: f64,
    /// Radial fall-off: gain × (1 − vignetting·r²), r = 1 at the frame corners.
    pub vignetting: f64,
    pub noise: Noise,
    /// Blur of the camera's optics on the projected light: a Gaussian of this σ, camera pixels
    /// (0: none, the default). A lens focused on the surface has a modulation transfer of about
    /// 50 % at 0.2–0.3 cycles per pixel in webcams; a Gaussian with the same MTF50 has
    /// σ = 0.187 / f50, about 0.6–0.9 px. Each camera pixel then mixes its neighbours' light,
    /// which a per-pixel colour model cannot undo.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub blur_px: f64,
}

fn is_zero(v: &f64) -> bool {
    *v == 0.0
}

/// Poisson-Gaussian sensor noise on the linear signal s ∈ \[0,1\]: variance = shot·s + read².
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Noise {
    pub shot: f64,
    pub read: f64,
}

/// Projector: pinhole optics, per-channel response, primaries, black level, vignetting, defocus.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ProjectorModel {
    /// Frame size in projector pixels.
    pub width: usize,
    pub height: usize,
    /// Horizontal field of view in degrees (square pixels, principal point at the centre).
    pub hfov_deg: f64,
    pub pose: Pose,
    /// Per-channel response: drive = (input level)^gamma per channel, input quantised to 8 bits.
    pub gamma: [f64; 3],
    /// Primaries: emitted RGB = mixing · drive + black (rows = emitted channels). Non-negative.
    pub mixing: [[f64; 3]; 3],
    /// Light emitted for an all-black input (inside the projector frame only).
    pub black: [f64; 3],
    /// Radial fall-off of the emitted light: 1 − vignetting·r², r = 1 at the frame corners.
    pub vignetting: f64,
    /// Defocus blur: Gaussian standard deviation in projector pixels (0 = sharp).
    pub defocus_px: f64,
    /// A white segment (single-chip DLP projectors whose colour wheel has a clear segment):
    /// extra light white_boost·min(d_r, d_g, d_b)·(M·1), the projector's white scaled by the
    /// smallest of the three drives, so a grey gets brighter than its primaries add up to and
    /// a saturated colour does not (0: none, the default). Cross-talk that depends on the
    /// level of every channel at once: a per-pixel linear colour model cannot express it.
    /// Magnitude: projector makers publish white and colour light output (the latter measured
    /// as the sum of the red, green and blue outputs); single-chip DLP projectors with a white
    /// segment often list white at about twice their colour light output, i.e. 1.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub white_boost: f64,
    /// Cross-talk of a three-panel LCD projector that changes with the level and across the
    /// frame (none by default). The off-diagonal entries of `mixing` are the light of one
    /// panel's band that lands in a neighbouring channel, from the edge of that band nearest
    /// it. `mixing` holds them at full drive, at the centre column.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub lcd_crosstalk: Option<LcdCrosstalk>,
}

/// How the leak of one LCD panel's band into a neighbouring channel (an off-diagonal entry
/// M_ij of the projector's mixing, j the panel, i the channel) varies. A per-pixel linear
/// colour model fits one matrix per pixel, so it can follow the change across the frame but
/// not the change with level.
///
/// - **With level:** a liquid-crystal cell's retardation is set for the centre wavelength λ of
///   its band, so the band edge at λ_e transmits T_e(d) ≠ d at a drive d where the centre
///   transmits d. From T = sin²(π·Γ/λ), the edge's share at drive d relative to full drive goes
///   from k² at black to 1 at full, k = λ/λ_e. The simulator takes it linear in d between
///   those two: leak = M_ij·d·(k² + (1 − k²)·d). That understates the sine law's change
///   (by at most 4–7 % of the leak, near d = 0.75, for offsets 0.05–0.08) and keeps the
///   leak's slope finite at full drive, where the sine law's is not. The edge towards shorter wavelengths (red into green,
///   green into blue) has k = 1/(1 − `edge_offset`) > 1, so it leaks relatively more at low
///   levels. The edge towards longer wavelengths has k = 1/(1 + `edge_offset`) < 1.
/// - **Across the frame:** the dichroic mirrors that split the lamp's light meet it at about
///   45°, and at an angle θ a thin-film edge sits at λ·√(1 − sin²θ/n²). With n ≈ 1.8 that is
///   about 1.5 nm per degree. A field that spans ±5° at the mirrors then moves the edges by
///   about ±8 nm from one side of the frame to the other. Against overlaps of some 15–20 nm
///   between neighbouring bands, the leaks change by some tens of percent. The simulator
///   scales the leaks towards shorter wavelengths by (1 + `across`·u) and those towards
///   longer ones by (1 − `across`·u), with u from −1 (left column) to +1 (right). So one side
///   of the frame is tinted one way and the other side the other way, the colour shading of
///   three-panel projectors.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LcdCrosstalk {
    /// Offset of the leaking band edges from their band's centre, as a fraction of its
    /// wavelength, in [0, 0.2]: about 0.05–0.08 for bands 50–90 nm wide.
    pub edge_offset: f64,
    /// Relative change of the leaks from the centre column to the left and right edges of the
    /// frame, in [0, 0.9]: about 0.2–0.5 by the estimate above.
    pub across: f64,
}

/// Analytic surfaces, each a height field z = h(x, y) seen from the camera (the solid lies
/// behind it, z ≥ h), evaluated on |x|, |y| ≤ [`SURFACE_EXTENT`] metres.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum Surface {
    /// z = distance + tan(tilt_x)·x + tan(tilt_y)·y.
    Plane { distance: f64, tilt_deg: [f64; 2] },
    /// Vertical cylinder of `radius` whose front (convex: nearest; concave: farthest) point is at
    /// x = 0, z = `distance`.
    Cylinder {
        distance: f64,
        radius: f64,
        convex: bool,
    },
    /// z = distance + amplitude·sin(2π·(x·cos a + y·sin a)/period + phase), like a curtain.
    Wave {
        distance: f64,
        amplitude: f64,
        period: f64,
        angle_deg: f64,
        phase_deg: f64,
    },
    /// Inside corner of two walls meeting at a vertical edge at x = `edge_x`, z = `distance`:
    /// z = distance − slope·|x − edge_x|.
    Corner {
        distance: f64,
        slope: f64,
        edge_x: f64,
    },
    /// A plane at `distance` for x < `edge_x` and a block `depth` metres nearer for x ≥ `edge_x`,
    /// joined by a vertical face (the block casts a shadow when the projector is to the right).
    Step {
        distance: f64,
        depth: f64,
        edge_x: f64,
    },
}

/// Half-size of the square on which surfaces are defined (metres). Beyond it the height field
/// is extended by its value at the border.
pub const SURFACE_EXTENT: f64 = 4.0;

/// Surface reflectance (linear, in \[0,1\] per channel), fixed to the surface (x, y).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum Albedo {
    Uniform {
        rgb: [f64; 3],
    },
    /// Procedural texture from the seed: smooth value noise picks colours along `palette`
    /// (piecewise linear), a second noise field darkens by up to `shade`, and `sharpness`
    /// (≥ 1) turns smooth blends into crisper patches. `scale` is the feature size in metres.
    Texture {
        palette: Vec<[f64; 3]>,
        scale: f64,
        shade: f64,
        sharpness: f64,
    },
}

/// Ambient light falling on the surface (irradiance, relative to a full-white projector):
/// offset + gradient·ramp, where ramp goes from 0 to 1 across the camera view along
/// `direction_deg` (0 = increasing to the right, 90 = increasing downwards).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Ambient {
    pub offset: [f64; 3],
    pub gradient: [f64; 3],
    pub direction_deg: f64,
}

impl Default for Ambient {
    fn default() -> Self {
        Ambient {
            offset: [0.002, 0.002, 0.0025],
            gradient: [0.0; 3],
            direction_deg: 0.0,
        }
    }
}

/// Blinn-Phong highlight of the projector's light: radiance += strength·(N·H)^shininess ×
/// incident projector light (untinted by the albedo).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Specular {
    pub strength: f64,
    pub shininess: f64,
}

/// Static glare: radiance += rgb·exp(−d²/(2·radius²)), d the distance in camera pixels from
/// `centre`; `centre` and `radius` are fractions of the camera width and height.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Glare {
    pub rgb: [f64; 3],
    pub centre: [f64; 2],
    pub radius: f64,
}

/// One bounce of diffusely reflected projector light: irradiance += strength × (Gaussian blur of
/// the directly reflected radiance), blur σ = `radius` × camera width (camera space).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Interreflection {
    pub strength: f64,
    pub radius: f64,
}

/// Sub-surface scattering: a share of the diffusely reflected projector light travels under the
/// surface and leaves it a few millimetres from where it entered, further in some channels than
/// in others. The coloured top layer filters that light on the way in and on the way out, so
/// radiance R = ρ·g·E·(1 − share) + share·√ρ·K_c ∗ (√ρ·g·E), with K_c a Gaussian of σ =
/// `radius_mm[c]` on the surface (converted to camera pixels at the surface's distance along the
/// camera's axis). A per-pixel model cannot express it: each pixel's colour depends on its
/// neighbours' light, channel by channel.
///
/// Magnitude: the diffusion length 1/σ_tr, σ_tr = √(3·σ_a·(σ_a + σ_s′)), of measured scattering
/// and absorption coefficients (Jensen et al. 2001, "A Practical Model for Subsurface Light
/// Transport"): skin 3.7, 1.4 and 0.7 mm in red, green and blue; marble 8.5, 5.6 and 4.0 mm.
/// Most diffuse reflection of such materials is sub-surface; the share of light reflected at the
/// surface itself is small.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Subsurface {
    /// Share of the diffuse reflection that travels under the surface, in [0, 1].
    pub share: f64,
    /// σ of the lateral spread per channel (R, G, B), millimetres on the surface.
    pub radius_mm: [f64; 3],
}

/// Timing of the virtual camera: frame rate, frames of delay between exposure and delivery,
/// and the probability that an exposure is dropped.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Latency {
    pub fps: f64,
    pub delay_frames: u32,
    pub drop_rate: f64,
}

impl Default for Latency {
    fn default() -> Self {
        Latency {
            fps: 30.0,
            delay_frames: 2,
            drop_rate: 0.02,
        }
    }
}

/// Projector movement after calibration: a rotation that shifts its image on the surface by
/// about `shift_px` projector pixels (x right, y down).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Drift {
    pub shift_px: [f64; 2],
}

impl CameraModel {
    /// The frame size, camera pixels.
    pub fn size(&self) -> ImageSize {
        ImageSize::new(self.width, self.height)
    }
}

impl ProjectorModel {
    /// The frame size, projector pixels.
    pub fn size(&self) -> ImageSize {
        ImageSize::new(self.width, self.height)
    }
}

impl Scene {
    /// Rescales the scene to other camera and projector resolutions, keeping the physical
    /// scene (fields of view, poses, surfaces) and the blur in physical terms (defocus and drift
    /// scale with the projector width, the camera's blur with the camera width). Sizes must be at least 2×2.
    pub fn with_resolution(mut self, camera: ImageSize, projector: ImageSize) -> Self {
        let k = projector.width as f64 / self.projector.width as f64;
        // The camera's blur scales with the camera width.
        self.camera.blur_px *= camera.width as f64 / self.camera.width.max(1) as f64;
        self.camera.width = camera.width;
        self.camera.height = camera.height;
        self.projector.width = projector.width;
        self.projector.height = projector.height;
        self.projector.defocus_px *= k;
        if let Some(d) = &mut self.drift {
            d.shift_px = [d.shift_px[0] * k, d.shift_px[1] * k];
        }
        // A set's other projectors take the same resolution, their defocus scaled alike.
        for p in &mut self.more_projectors {
            p.defocus_px *= projector.width as f64 / p.width.max(1) as f64;
            p.width = projector.width;
            p.height = projector.height;
        }
        self
    }

    /// Every projector of the scene, `projector` first.
    pub fn projectors(&self) -> Vec<&ProjectorModel> {
        std::iter::once(&self.projector)
            .chain(&self.more_projectors)
            .collect()
    }

    /// The scene as projector `k` alone lights it (0: `projector`), the others taken away: how
    /// a set is simulated, one projector at a time. `drift` moves the first projector only.
    /// `None` past the last projector.
    pub fn alone(&self, k: usize) -> Option<Scene> {
        let p = self.projectors().get(k).map(|p| (*p).clone())?;
        Some(Scene {
            projector: p,
            more_projectors: Vec::new(),
            drift: if k == 0 { self.drift.clone() } else { None },
            ..self.clone()
        })
    }

    /// Overrides the virtual camera's frame rate (Hz) and the projector-to-camera delay (ms,
    /// rounded to whole camera frames at the resulting rate).
    pub fn with_timing(mut self, fps: Option<f64>, latency_ms: Option<f64>) -> Self {
        if let Some(fps) = fps {
            self.latency.fps = fps;
        }
        if let Some(ms) = latency_ms {
            self.latency.delay_frames = (ms / 1e3 * self.latency.fps).round() as u32;
        }
        self
    }

    /// Checks values the simulator relies on; the error names the field.
    pub fn validate(&self) -> Result<()> {
        self.validate_devices()?;
        for k in 1..self.projectors().len() {
            if let Some(one) = self.alone(k) {
                one.validate_devices().map_err(|e| match e {
                    Error::Input(why) => Error::Input(format!(
                        "{why} (projector {} of the set: more_projectors[{}])",
                        k + 1,
                        k - 1
                    )),
                    other => other,
                })?;
            }
        }
        self.validate_albedo()?;
        self.validate_surface()?;
        self.validate_effects()
    }

    /// The error for field `what` of this scene: `Err` with `why` it is invalid.
    fn bad(&self, what: &str, why: &str) -> Result<()> {
        Err(Error::Input(format!("scene {:?}: {what} {why}", self.name)))
    }

    /// Camera and projector: sizes (pixels), fields of view (degrees), colour mixing, response,
    /// vignetting, noise, defocus (projector pixels) and the latency model.
    fn validate_devices(&self) -> Result<()> {
        let c = &self.camera;
        let p = &self.projector;
        if c.width < 2 || c.height < 2 {
            return self.bad("camera.width/height", "must be at least 2");
        }
        if p.width < 2 || p.height < 2 {
            return self.bad("projector.width/height", "must be at least 2");
        }
        let max = crate::raster::ImageSize::MAX_PIXELS as u128;
        for (name, w, h) in [
            ("camera.width/height", c.width, c.height),
            ("projector.width/height", p.width, p.height),
        ] {
            if w as u128 * h as u128 > max {
                return self.bad(
                    name,
                    &format!("{w}x{h} is more than the 8192x8192 pixels compend accepts"),
                );
            }
        }
        for (name, fov) in [
            ("camera.hfov_deg", c.hfov_deg),
            ("projector.hfov_deg", p.hfov_deg),
        ] {
            if !(fov > 1.0 && fov < 170.0) {
                return self.bad(name, "must be between 1 and 170 degrees");
            }
        }
        for (name, m) in [
            ("camera.mixing", &c.mixing),
            ("projector.mixing", &p.mixing),
        ] {
            if m.iter().flatten().any(|&v| !(v >= 0.0 && v.is_finite())) {
                return self.bad(name, "entries must be finite and non-negative");
            }
            let det = nalgebra::Matrix3::from_fn(|r, k| m[r][k]).determinant();
            if det.abs() < 1e-6 {
                return self.bad(name, "must be invertible");
            }
        }
        if !above(c.exposure, 0.0) || !above(c.gamma, 0.0) {
            return self.bad("camera.exposure/gamma", "must be positive");
        }
        if p.gamma.iter().any(|&g| !above(g, 0.0)) {
            return self.bad("projector.gamma", "must be positive");
        }
        if !(0.0..1.0).contains(&c.vignetting) || !(0.0..1.0).contains(&p.vignetting) {
            return self.bad("vignetting", "must be in [0,1)");
        }
        if c.noise.shot < 0.0 || c.noise.read < 0.0 {
            return self.bad("camera.noise", "must be non-negative");
        }
        if !(p.defocus_px >= 0.0 && p.defocus_px <= 64.0) {
            return self.bad("projector.defocus_px", "must be in [0, 64]");
        }
        if !(p.white_boost >= 0.0 && p.white_boost <= 4.0) {
            return self.bad("projector.white_boost", "must be in [0, 4]");
        }
        if let Some(lcd) = &p.lcd_crosstalk {
            if !(lcd.edge_offset >= 0.0 && lcd.edge_offset <= 0.2) {
                return self.bad("projector.lcd_crosstalk.edge_offset", "must be in [0, 0.2]");
            }
            if !(lcd.across >= 0.0 && lcd.across <= 0.9) {
                return self.bad("projector.lcd_crosstalk.across", "must be in [0, 0.9]");
            }
        }
        if !(c.blur_px >= 0.0 && c.blur_px <= 16.0) {
            return self.bad("camera.blur_px", "must be in [0, 16]");
        }
        if !above(self.latency.fps, 0.0) || !(0.0..0.9).contains(&self.latency.drop_rate) {
            return self.bad("latency", "needs fps > 0 and drop_rate in [0, 0.9)");
        }
        Ok(())
    }

    /// The albedo: colours in \[0,1\], a texture's scale (metres), shade and sharpness.
    fn validate_albedo(&self) -> Result<()> {
        match &self.albedo {
            Albedo::Uniform { rgb } if rgb.iter().any(|v| !(0.0..=1.0).contains(v)) => {
                return self.bad("albedo.rgb", "must be in [0,1]");
            }
            Albedo::Texture {
                palette,
                scale,
                shade,
                sharpness,
            } => {
                if palette.is_empty() || palette.iter().flatten().any(|v| !(0.0..=1.0).contains(v))
                {
                    return self.bad("albedo.palette", "needs colours in [0,1]");
                }
                if !above(*scale, 0.0) || !(0.0..=1.0).contains(shade) || !at_least(*sharpness, 1.0)
                {
                    return self.bad(
                        "albedo",
                        "needs scale > 0, shade in [0,1] and sharpness >= 1",
                    );
                }
            }
            _ => {}
        }
        Ok(())
    }

    /// The surface's distance, radius and period (metres).
    fn validate_surface(&self) -> Result<()> {
        let dist = match &self.surface {
            Surface::Plane { distance, .. }
            | Surface::Cylinder { distance, .. }
            | Surface::Wave { distance, .. }
            | Surface::Corner { distance, .. }
            | Surface::Step { distance, .. } => *distance,
        };
        if !above(dist, 0.1) {
            return self.bad("surface.distance", "must be more than 0.1 m");
        }
        match self.surface {
            Surface::Cylinder { radius, .. } if !above(radius, 0.05) => {
                return self.bad("surface.radius", "must be more than 0.05 m");
            }
            Surface::Wave { period, .. } if !above(period, 1e-3) => {
                return self.bad("surface.period", "must be more than 1 mm");
            }
            _ => {}
        }
        Ok(())
    }

    /// Inter-reflection and specular highlights.
    fn validate_effects(&self) -> Result<()> {
        if let Some(ir) = &self.interreflection
            && (!at_least(ir.strength, 0.0) || !above(ir.radius, 0.0))
        {
            return self.bad("interreflection", "needs strength >= 0 and radius > 0");
        }
        if let Some(ss) = &self.subsurface
            && (!(0.0..=1.0).contains(&ss.share)
                || ss.radius_mm.iter().any(|r| !(0.0..=50.0).contains(r)))
        {
            return self.bad(
                "subsurface",
                "needs share in [0, 1] and radius_mm in [0, 50] per channel",
            );
        }
        if let Some(s) = &self.specular
            && (!at_least(s.strength, 0.0) || !at_least(s.shininess, 1.0))
        {
            return self.bad("specular", "needs strength >= 0 and shininess >= 1");
        }
        Ok(())
    }
}

/// `v` is a number greater than `min` (false for NaN).
fn above(v: f64, min: f64) -> bool {
    v.is_finite() && v > min
}

/// `v` is a number of at least `min` (false for NaN).
fn at_least(v: f64, min: f64) -> bool {
    v.is_finite() && v >= min
}
