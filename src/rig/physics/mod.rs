//! The simulator: a scene turned into per-pixel maps once, so that a capture is a gather plus
//! per-pixel colour maths (plus a blur for defocus), noise and quantisation.
//!
//! Forward model for a projector input image P (projector space, values in \[0,1\]):
//!
//! 1. projector: input quantised to 8 bits, drive d = level^γ_c per channel, emitted light
//!    e = M_p·d + w·min(d) + black (linear, projector space; w the white segment's light,
//!    zero for most scenes; with an LCD's cross-talk the off-diagonal terms of M_p·d depend on
//!    the drive and the column, see [`super::scene::LcdCrosstalk`]); optional defocus blurs e (Gaussian, zero padding: no light comes
//!    from outside the frame);
//! 2. geometry: each camera pixel sees one surface point, lit by the emitted light sampled
//!    bilinearly at the projector coordinate of that point (zeros outside the frame), E_i;
//! 3. surface: radiance R_i = ρ_i·g_i·E_i + spec_i·E_i + ρ_i·I_i + ρ_i·A_i + glare_i, where
//!    g_i = visibility × cos(incidence) × distance fall-off × projector vignetting, spec_i the
//!    projector highlight, I_i one inter-reflection bounce (strength × wide blur of ρ·g·E),
//!    A_i ambient irradiance; with sub-surface scattering a share of ρ_i·g_i·E_i is replaced
//!    by √ρ_i·(K_c ∗ √ρ·g·E)_i (a Gaussian per channel, camera pixels);
//! 4. camera: sensor s_i = exposure·vignetting_i·M_c·R_i, optionally blurred by the optics
//!    (Gaussian, camera pixels, zero padding; ambient light and glare are not blurred: they are
//!    smooth); Poisson-Gaussian noise; clip to \[0,1\];
//!    encoded value s^(1/γ); 8-bit quantisation (round to nearest level).
//!
//! Steps 1 (after the response curve) to the sensor signal are linear in the drive d, except
//! for the white segment's min(d), which is piecewise linear and positively homogeneous, and an
//! LCD's cross-talk, quadratic in d; the oracle ([`super::oracle`]) uses that operator and the
//! adjoint of its Jacobian.
//!
//! Spaces: the per-pixel maps and sensor signals are in camera pixels (row-major, interleaved
//! RGB), emitted light and drives in projector pixels; pixel centres at integer coordinates.
//!
//! - this module: the [`Simulator`] (built once per scene, seed and [`Phase`]), captures, masks
//!   and correspondences;
//! - `pixel`: ray casting and shading of one camera pixel (step 2 and 3's per-pixel factors);
//! - `operator`: the linear operator (emission → sensor) and its adjoint;
//! - `bounce`: the inter-reflection of step 3;
//! - `subsurface`: the sub-surface scattering of step 3;
//! - `kernels`: blurs, small matrix helpers, the parallel loops and the noise hashing.

use std::sync::OnceLock;

use super::geom::{Pinhole, Shape};
use super::scene::{Pose, Scene};
use crate::error::{Error, Result};
use crate::raster::{CamImage, Camera, ImageSize, Mask, PrjImage};
use rayon::prelude::*;

mod bounce;
mod kernels;
mod operator;
mod pixel;
mod set;
mod subsurface;
#[cfg(test)]
mod tests;

use bounce::Bounce;
use kernels::{CHUNK, approx_normal, gaussian_kernel, par_rows};
pub(crate) use kernels::{mat3, mix64};
use pixel::{PixelMaps, camera_maps};
pub use set::SetSimulator;
use subsurface::Subsurface;

/// Which projector pose the simulator uses: the one at calibration, or the moved one of
/// [`Scene::drift`] (identical when the scene has no drift).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Phase {
    Calibration,
    AfterDrift,
}

/// Four bilinear taps into projector space: the pixel at `base` and its right, lower and
/// lower-right neighbours, weights in that order (zero for taps outside the frame).
#[derive(Clone, Copy, Debug, Default)]
struct Tap {
    base: u32,
    w: [f32; 4],
}

/// A scene prepared for simulation. Immutable and `Sync`: captures can run from any thread.
#[derive(Debug)]
pub struct Simulator {
    scene: Scene,
    seed: u64,
    phase: Phase,
    cam: Pinhole,
    prj: Pinhole,
    shape: Shape,
    // Camera-space maps, one entry per camera pixel (row-major).
    taps: Vec<Tap>,
    prj_xy: Vec<[f32; 2]>,
    lit: Vec<bool>,
    shadow: Vec<bool>,
    diffuse: Vec<[f32; 3]>,
    spec: Vec<f32>,
    albedo: Vec<[f32; 3]>,
    gain: Vec<f32>,
    constant: Vec<[f32; 3]>,
    preview: CamImage,
    // Global terms.
    prj_lut: [[f32; 256]; 3],
    prj_mix: [[f32; 3]; 3],
    prj_black: [f32; 3],
    /// The white segment's light per unit of the smallest drive: white_boost·M_p·1.
    prj_white: [f32; 3],
    /// The LCD cross-talk's constants, when the scene has it.
    prj_lcd: Option<operator::LcdTerms>,
    cam_mix: [[f32; 3]; 3],
    defocus: Option<Vec<f32>>,
    /// The camera optics' blur kernel (camera pixels), when the scene has one.
    cam_blur: Option<Vec<f32>>,
    bounce: Option<Bounce>,
    /// Sub-surface scattering, when the scene has it.
    subsurface: Option<Subsurface>,
    /// Sensor signal at which the encoded output reaches level k + ½, k = 0..254.
    thresholds: Vec<f32>,
    /// For a signal bucket (the f32 bits of a signal above `thresholds[0]`, shifted right by
    /// [`QUANT_SHIFT`]: 1024 buckets an octave, each narrower than the gap between two
    /// thresholds), the level at its lower edge.
    bucket_level: Vec<u8>,
    noise: (f32, f32),
    prj_to_cam: OnceLock<Vec<[f32; 2]>>,
}

/// Bits of a signal's f32 below its quantisation bucket: 1024 buckets an octave, about 0.1 %
/// wide, where two levels' thresholds lie at least 0.39 % × γ apart.
const QUANT_SHIFT: u32 = 13;

impl Simulator {
    /// Prepares `scene` (validated) with texture seed `seed` and the projector pose of `phase`.
    pub fn new(scene: &Scene, seed: u64, phase: Phase) -> Result<Self> {
        scene.validate()?;
        if !scene.more_projectors.is_empty() {
            return Err(Error::Input(format!(
                "scene {:?} is a set of {} projectors: compend calibrates and plays one projector \
                 at a time so far; `compend sim sheet --scene {}` shows the set and its joint \
                 physical ceiling",
                scene.name,
                scene.projectors().len(),
                scene.name
            )));
        }
        let c = &scene.camera;
        let p = &scene.projector;
        let cam = Pinhole::new(c.width, c.height, c.hfov_deg, &c.pose);
        let prj_pose = projector_pose(scene, phase);
        let prj = Pinhole::new(p.width, p.height, p.hfov_deg, &prj_pose);
        let shape = Shape::new(&scene.surface);

        let m3 = |m: &[[f64; 3]; 3]| m.map(|r| r.map(|v| v as f32));
        let cam_mix = m3(&c.mixing);
        let (cw, chh) = (c.width, c.height);
        let pixels = camera_maps(scene, seed, &cam, &prj, &shape, cam_mix);

        let n = cw * chh;
        let mut sim = Simulator {
            scene: scene.clone(),
            seed,
            phase,
            cam,
            prj,
            shape,
            taps: Vec::with_capacity(n),
            prj_xy: Vec::with_capacity(n),
            lit: Vec::with_capacity(n),
            shadow: Vec::with_capacity(n),
            diffuse: Vec::with_capacity(n),
            spec: Vec::with_capacity(n),
            albedo: Vec::with_capacity(n),
            gain: Vec::with_capacity(n),
            constant: Vec::with_capacity(n),
            preview: CamImage::new(cw, chh),
            prj_lut: [[0.0; 256]; 3],
            prj_mix: m3(&p.mixing),
            prj_black: p.black.map(|v| v as f32),
            prj_white: p
                .mixing
                .map(|row| (p.white_boost * row.iter().sum::<f64>()) as f32),
            prj_lcd: p.lcd_crosstalk.as_ref().map(operator::LcdTerms::new),
            cam_mix,
            defocus: None,
            cam_blur: None,
            bounce: None,
            subsurface: None,
            thresholds: Vec::new(),
            bucket_level: Vec::new(),
            noise: (c.noise.shot as f32, c.noise.read as f32),
            prj_to_cam: OnceLock::new(),
        };
        sim.store_pixels(pixels)?;
        sim.set_global_terms();
        Ok(sim)
    }

    /// Moves the per-pixel maps into the simulator's camera-space arrays (row-major) and builds
    /// the surface preview from them.
    fn store_pixels(&mut self, pixels: Vec<PixelMaps>) -> Result<()> {
        let ImageSize {
            width: cw,
            height: chh,
        } = self.camera_size();
        let n = cw * chh;
        let sim = self;
        let mut preview = Vec::with_capacity(n * 3);
        for px in pixels {
            sim.taps.push(px.tap);
            sim.prj_xy.push(px.prj_xy);
            sim.lit.push(px.lit);
            sim.shadow.push(px.shadow);
            sim.diffuse.push(px.diffuse);
            sim.spec.push(px.spec);
            sim.albedo.push(px.albedo);
            sim.gain.push(px.gain);
            sim.constant.push(px.constant);
            preview.extend_from_slice(&px.preview);
        }
        sim.preview = CamImage::from_vec(cw, chh, preview)?;
        Ok(())
    }

    /// The global terms of the scene: the projector's response table per 8-bit level, the
    /// defocus kernel (projector pixels), the inter-reflection bounce and the camera's
    /// quantisation tables.
    fn set_global_terms(&mut self) {
        let sim = self;
        let scene = &sim.scene;
        let (c, p) = (&scene.camera, &scene.projector);
        let (cw, chh) = (c.width, c.height);
        for (ch, lut) in sim.prj_lut.iter_mut().enumerate() {
            for (level, v) in lut.iter_mut().enumerate() {
                *v = (level as f64 / 255.0).powf(p.gamma[ch]) as f32;
            }
        }
        if p.defocus_px > 0.05 {
            sim.defocus = Some(gaussian_kernel(p.defocus_px));
        }
        if c.blur_px > 0.05 {
            sim.cam_blur = Some(gaussian_kernel(c.blur_px));
        }
        if let Some(ir) = &scene.interreflection
            && ir.strength > 0.0
        {
            sim.bounce = Some(Bounce::new(cw, chh, ir.strength, ir.radius));
        }
        if let Some(ss) = &scene.subsurface
            && ss.share > 0.0
        {
            // Millimetres on the surface to camera pixels, at the surface's distance along the
            // camera's axis.
            let axis = sim.cam.ray(sim.cam.cx, sim.cam.cy);
            let dist = sim
                .shape
                .intersect(&sim.cam.centre, &axis)
                .map_or(2.0, |t| t * axis.norm());
            let px_per_mm = sim.cam.f / (dist * 1e3);
            sim.subsurface = Some(Subsurface::new(
                ss.share,
                ss.radius_mm.map(|r| r * px_per_mm),
                (cw, chh),
                &sim.diffuse,
                &sim.albedo,
            ));
        }
        // Quantisation thresholds of the encoded output: level k+1 starts where
        // s^(1/γ) = (k + ½)/255.
        sim.thresholds = (0..255)
            .map(|k| ((k as f64 + 0.5) / 255.0).powf(c.gamma) as f32)
            .collect();
        // The thresholds rise with the level, so one pass finds every bucket's.
        let (low, high) = quant_buckets(&sim.thresholds);
        let mut level = 0;
        let bucket_level = (low..=high)
            .map(|b| {
                let s = f32::from_bits(b << QUANT_SHIFT);
                while level < sim.thresholds.len() && sim.thresholds[level] <= s {
                    level += 1;
                }
                level as u8
            })
            .collect();
        sim.bucket_level = bucket_level;
    }

    pub fn scene(&self) -> &Scene {
        &self.scene
    }
    pub fn seed(&self) -> u64 {
        self.seed
    }
    pub fn phase(&self) -> Phase {
        self.phase
    }
    /// (width, height) of the camera frame.
    pub fn camera_size(&self) -> ImageSize {
        ImageSize::new(self.cam.width, self.cam.height)
    }
    /// (width, height) of the projector frame.
    pub fn projector_size(&self) -> ImageSize {
        ImageSize::new(self.prj.width, self.prj.height)
    }

    /// One capture of projector image `prj`: noise drawn from (seed, `frame`), clipped, encoded
    /// and quantised to 8-bit levels (values k/255).
    pub fn capture(&self, prj: &PrjImage, frame: u64) -> Result<CamImage> {
        let s = self.clean_signal(prj)?;
        Ok(self.finish(&s, Some(frame)))
    }

    /// The mean of `n` captures of `prj` (frames `first` to `first + n − 1`, each with its own
    /// noise), as a capture protocol averages frames; `n = 1` is [`Self::capture`].
    pub fn capture_mean(&self, prj: &PrjImage, first: u64, n: usize) -> Result<CamImage> {
        let s = self.clean_signal(prj)?;
        let mut sum = self.finish(&s, Some(first));
        for f in 1..n.max(1) as u64 {
            let next = self.finish(&s, Some(first + f));
            for (a, b) in sum.data_mut().iter_mut().zip(next.data()) {
                *a += b;
            }
        }
        if n > 1 {
            let k = 1.0 / n as f32;
            sum.data_mut().iter_mut().for_each(|v| *v *= k);
        }
        Ok(sum)
    }

    /// The noise-free sensor signal for `prj` (linear, camera space, interleaved RGB, not yet
    /// clipped): what every capture of it scatters around.
    pub fn clean_signal(&self, prj: &PrjImage) -> Result<Vec<f32>> {
        self.check_prj(prj)?;
        let e = self.emission(prj);
        let mut s = self.sensor(&e);
        self.add_constant(&mut s);
        Ok(s)
    }

    /// The camera's output for a sensor signal: noise for `frame` (none for `None`), clipping,
    /// response curve and 8-bit quantisation.
    pub fn finish(&self, signal: &[f32], frame: Option<u64>) -> CamImage {
        self.finish_exposed(signal, 1.0, frame)
    }

    /// [`Simulator::finish`] of the signal times `exposure` (a factor of the scene's exposure
    /// time: it scales all light reaching the sensor, ambient included), without a scaled copy
    /// of the signal. Exposure 1 gives `finish`'s image to the bit (`x · 1 = x` in f32).
    pub fn finish_exposed(&self, signal: &[f32], exposure: f32, frame: Option<u64>) -> CamImage {
        let (shot, read) = self.noise;
        let key = frame.map(|f| mix64(self.seed ^ mix64(f.wrapping_add(0x5eed_f4a3))));
        let read2 = read * read;
        let mut data = vec![0f32; signal.len()];
        data.par_chunks_mut(CHUNK)
            .zip(signal.par_chunks(CHUNK))
            .enumerate()
            .for_each(|(c, (out, sig))| {
                for (j, (o, &s)) in out.iter_mut().zip(sig).enumerate() {
                    let s = s * exposure;
                    let s = match key {
                        Some(k) => {
                            let i = (c * CHUNK + j) as u64;
                            let sd = (shot * s.max(0.0) + read2).sqrt();
                            s + sd * approx_normal(mix64(k.wrapping_add(i)))
                        }
                        None => s,
                    };
                    *o = self.quantise(s) as f32 / 255.0;
                }
            });
        CamImage::from_vec(self.cam.width, self.cam.height, data)
            .expect("the signal has the camera's size")
    }

    /// Noise-free camera output for `prj` without quantisation: clip and response curve only.
    pub fn expected(&self, prj: &PrjImage) -> Result<CamImage> {
        let s = self.clean_signal(prj)?;
        let inv = 1.0 / self.scene.camera.gamma as f32;
        let data = s.iter().map(|&v| v.clamp(0.0, 1.0).powf(inv)).collect();
        CamImage::from_vec(self.cam.width, self.cam.height, data)
    }

    /// Camera pixels whose surface point the projector frame lights (inside the frame, facing
    /// the projector, not shadowed): the true projector FOV mask.
    pub fn lit_mask(&self) -> Mask<Camera> {
        let ImageSize {
            width: w,
            height: h,
        } = self.camera_size();
        Mask::from_vec(w, h, self.lit.clone()).expect("one entry per camera pixel")
    }

    /// Camera pixels whose surface point lies in the projector's frustum but is hidden from the
    /// projector by another part of the surface or faces away from it (self-occlusion).
    pub fn shadow_mask(&self) -> Mask<Camera> {
        let ImageSize {
            width: w,
            height: h,
        } = self.camera_size();
        Mask::from_vec(w, h, self.shadow.clone()).expect("one entry per camera pixel")
    }

    /// For every camera pixel (row-major), the projector pixel coordinate of the surface point
    /// it sees (pixel centres at integers), or NaN where the projector does not reach it.
    pub fn projector_coords(&self) -> &[[f32; 2]] {
        &self.prj_xy
    }

    /// For every projector pixel (row-major), the camera pixel coordinate where its light lands
    /// (pixel centres at integers), or NaN where no camera pixel sees it. Computed on first use.
    pub fn camera_coords(&self) -> &[[f32; 2]] {
        self.prj_to_cam.get_or_init(|| {
            let ImageSize {
                width: pw,
                height: ph,
            } = self.projector_size();
            par_rows(ph, |v| {
                (0..pw)
                    .map(|u| self.camera_coord_of(u as f64, v as f64))
                    .collect::<Vec<_>>()
            })
        })
    }

    /// The scene as a person would see it under plain room light (linear albedo × shading,
    /// encoded with γ 2.2), darkened where the projector does not reach.
    pub fn surface_preview(&self) -> &CamImage {
        &self.preview
    }

    fn camera_coord_of(&self, u: f64, v: f64) -> [f32; 2] {
        let nan = [f32::NAN; 2];
        let d = self.prj.ray(u, v);
        let Some(t) = self.shape.intersect(&self.prj.centre, &d) else {
            return nan;
        };
        let q = self.prj.centre + d * t;
        let n = self.shape.normal(&q);
        if n.dot(&(self.cam.centre - q)) <= 0.0 || !self.shape.reaches(&self.cam.centre, &q) {
            return nan;
        }
        match self.cam.project(&q) {
            Some((x, y)) => [x as f32, y as f32],
            None => nan,
        }
    }

    pub(crate) fn check_prj(&self, prj: &PrjImage) -> Result<()> {
        if prj.size() != self.projector_size() {
            return Err(Error::Shape(format!(
                "virtual projector of scene {:?} is {}, got a {}x{} projector image",
                self.scene.name,
                self.projector_size(),
                prj.width(),
                prj.height()
            )));
        }
        Ok(())
    }

    #[inline]
    fn quantise(&self, s: f32) -> u8 {
        let th = &self.thresholds;
        // NaN, and every signal below the first threshold, is level 0.
        if !th.first().is_some_and(|&t| s >= t) {
            return 0;
        }
        if s >= 1.0 {
            return 255;
        }
        let (low, _) = quant_buckets(th);
        let b = ((s.to_bits() >> QUANT_SHIFT) - low) as usize;
        let mut q = self.bucket_level[b.min(self.bucket_level.len() - 1)] as usize;
        // At most one threshold lies in a bucket: one comparison, without a branch to guess
        // (the noise makes it a coin toss); the loop only for a response steep enough to put
        // more there (γ under 0.26).
        q += usize::from(th.get(q).is_some_and(|&t| t <= s));
        while q < th.len() && th[q] <= s {
            q += 1;
        }
        q as u8
    }
}

/// The first and last quantisation bucket of signals from `thresholds[0]` to 1.
fn quant_buckets(thresholds: &[f32]) -> (u32, u32) {
    let first = thresholds
        .first()
        .copied()
        .unwrap_or(1.0)
        .max(f32::MIN_POSITIVE);
    (
        first.to_bits() >> QUANT_SHIFT,
        1f32.to_bits() >> QUANT_SHIFT,
    )
}

/// The projector pose of `phase`: the calibrated one, or for [`Phase::AfterDrift`] turned by the
/// scene's drift (projector pixels converted to angles through the focal length).
fn projector_pose(scene: &Scene, phase: Phase) -> Pose {
    let p = &scene.projector;
    let mut prj_pose = p.pose.clone();
    if let (Phase::AfterDrift, Some(drift)) = (phase, &scene.drift) {
        let f = Pinhole::new(p.width, p.height, p.hfov_deg, &p.pose).f;
        prj_pose.rotation_deg[0] += (drift.shift_px[0] / f).atan().to_degrees();
        prj_pose.rotation_deg[1] -= (drift.shift_px[1] / f).atan().to_degrees();
    }
    prj_pose
}
