//! The simulator: a scene turned into per-pixel maps once, so that a capture is a gather plus
//! per-pixel colour maths (plus a blur for defocus), noise and quantisation.
//!
//! Forward model for a projector input image P (projector space, values in \[0,1\]):
//!
//! 1. projector: input quantised to 8 bits, drive d = level^γ_c per channel, emitted light
//!    e = M_p·d + black (linear, projector space); optional defocus blurs e (Gaussian, zero
//!    padding: no light comes from outside the frame);
//! 2. geometry: each camera pixel sees one surface point, lit by the emitted light sampled
//!    bilinearly at the projector coordinate of that point (zeros outside the frame), E_i;
//! 3. surface: radiance R_i = ρ_i·g_i·E_i + spec_i·E_i + ρ_i·I_i + ρ_i·A_i + glare_i, where
//!    g_i = visibility × cos(incidence) × distance fall-off × projector vignetting, spec_i the
//!    projector highlight, I_i one inter-reflection bounce (strength × wide blur of ρ·g·E),
//!    A_i ambient irradiance;
//! 4. camera: sensor s_i = exposure·vignetting_i·M_c·R_i; Poisson-Gaussian noise; clip to \[0,1\];
//!    encoded value s^(1/γ); 8-bit quantisation (round to nearest level).
//!
//! Steps 1 (after the response curve) to the sensor signal are linear in the drive d; the oracle
//! ([`super::oracle`]) uses that operator and its adjoint.

use std::sync::OnceLock;

use super::geom::{Pinhole, Shape};
use super::scene::{Scene, Surface};
use super::texture::AlbedoField;
use crate::error::{Error, Result};
use crate::raster::{CamImage, Camera, Mask, PrjImage};
use rayon::prelude::*;

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

/// Inter-reflection on a coarse camera-space grid: box-average blocks of `block` pixels, blur,
/// bilinear upsampling back.
#[derive(Clone, Debug)]
struct Bounce {
    strength: f32,
    block: usize,
    cw: usize,
    ch: usize,
    kernel: Vec<f32>,
    /// Per fine column / row: (coarse index 0, coarse index 1, weight of index 1).
    xtaps: Vec<(usize, usize, f32)>,
    ytaps: Vec<(usize, usize, f32)>,
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
    cam_mix: [[f32; 3]; 3],
    defocus: Option<Vec<f32>>,
    bounce: Option<Bounce>,
    /// Sensor signal at which the encoded output reaches level k + ½, k = 0..254.
    thresholds: Vec<f32>,
    /// For a signal bucket floor(s·QUANT_BUCKETS), the level at its lower edge.
    bucket_level: Vec<u8>,
    noise: (f32, f32),
    prj_to_cam: OnceLock<Vec<[f32; 2]>>,
}

const QUANT_BUCKETS: usize = 4096;

impl Simulator {
    /// Prepares `scene` (validated) with texture seed `seed` and the projector pose of `phase`.
    pub fn new(scene: &Scene, seed: u64, phase: Phase) -> Result<Self> {
        scene.validate()?;
        let c = &scene.camera;
        let p = &scene.projector;
        let cam = Pinhole::new(c.width, c.height, c.hfov_deg, &c.pose);
        let mut prj_pose = p.pose.clone();
        if let (Phase::AfterDrift, Some(drift)) = (phase, &scene.drift) {
            let f = Pinhole::new(p.width, p.height, p.hfov_deg, &p.pose).f;
            prj_pose.rotation_deg[0] += (drift.shift_px[0] / f).atan().to_degrees();
            prj_pose.rotation_deg[1] -= (drift.shift_px[1] / f).atan().to_degrees();
        }
        let prj = Pinhole::new(p.width, p.height, p.hfov_deg, &prj_pose);
        let shape = Shape::new(&scene.surface);
        let albedo_field = AlbedoField::new(&scene.albedo, seed);

        // Reference distance for the fall-off: along the projector's optical axis to the surface.
        let axis = prj.ray(prj.cx, prj.cy);
        let d_ref = shape
            .intersect(&prj.centre, &axis)
            .map(|t| t * axis.norm())
            .unwrap_or_else(|| surface_distance(&scene.surface));

        let m3 = |m: &[[f64; 3]; 3]| m.map(|r| r.map(|v| v as f32));
        let cam_mix = m3(&c.mixing);
        let (cw, chh) = (c.width, c.height);
        let amb = &scene.ambient;
        let amb_dir = amb.direction_deg.to_radians();

        let ctx = PixelCtx {
            cam: &cam,
            prj: &prj,
            shape: &shape,
            albedo: &albedo_field,
            scene,
            d_ref,
            cam_mix,
            amb_dir: (amb_dir.cos(), amb_dir.sin()),
        };
        let pixels: Vec<PixelMaps> = par_rows(chh, |y| {
            (0..cw).map(|x| ctx.pixel(x, y)).collect::<Vec<_>>()
        });

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
            cam_mix,
            defocus: None,
            bounce: None,
            thresholds: Vec::new(),
            bucket_level: Vec::new(),
            noise: (c.noise.shot as f32, c.noise.read as f32),
            prj_to_cam: OnceLock::new(),
        };
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

        for (ch, lut) in sim.prj_lut.iter_mut().enumerate() {
            for (level, v) in lut.iter_mut().enumerate() {
                *v = (level as f64 / 255.0).powf(p.gamma[ch]) as f32;
            }
        }
        if p.defocus_px > 0.05 {
            sim.defocus = Some(gaussian_kernel(p.defocus_px));
        }
        if let Some(ir) = &scene.interreflection {
            if ir.strength > 0.0 {
                sim.bounce = Some(Bounce::new(cw, chh, ir.strength, ir.radius));
            }
        }
        // Quantisation thresholds of the encoded output: level k+1 starts where
        // s^(1/γ) = (k + ½)/255.
        sim.thresholds = (0..255)
            .map(|k| ((k as f64 + 0.5) / 255.0).powf(c.gamma) as f32)
            .collect();
        sim.bucket_level = (0..QUANT_BUCKETS)
            .map(|b| {
                let s = b as f32 / QUANT_BUCKETS as f32;
                sim.thresholds.iter().take_while(|&&t| t <= s).count() as u8
            })
            .collect();
        Ok(sim)
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
    pub fn camera_size(&self) -> (usize, usize) {
        (self.cam.width, self.cam.height)
    }
    /// (width, height) of the projector frame.
    pub fn projector_size(&self) -> (usize, usize) {
        (self.prj.width, self.prj.height)
    }

    /// One capture of projector image `prj`: noise drawn from (seed, `frame`), clipped, encoded
    /// and quantised to 8-bit levels (values k/255).
    pub fn capture(&self, prj: &PrjImage, frame: u64) -> Result<CamImage> {
        let s = self.clean_signal(prj)?;
        Ok(self.finish(&s, Some(frame)))
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
        let (shot, read) = self.noise;
        let key = frame.map(|f| mix64(self.seed ^ mix64(f.wrapping_add(0x5eed_f4a3))));
        let read2 = read * read;
        let mut data = vec![0f32; signal.len()];
        data.par_chunks_mut(CHUNK)
            .zip(signal.par_chunks(CHUNK))
            .enumerate()
            .for_each(|(c, (out, sig))| {
                for (j, (o, &s)) in out.iter_mut().zip(sig).enumerate() {
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
        let (w, h) = self.camera_size();
        Mask::from_vec(w, h, self.lit.clone()).expect("one entry per camera pixel")
    }

    /// Camera pixels whose surface point lies in the projector's frustum but is hidden from the
    /// projector by another part of the surface or faces away from it (self-occlusion).
    pub fn shadow_mask(&self) -> Mask<Camera> {
        let (w, h) = self.camera_size();
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
            let (pw, ph) = self.projector_size();
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

    fn check_prj(&self, prj: &PrjImage) -> Result<()> {
        if prj.size() != self.projector_size() {
            return Err(Error::Shape(format!(
                "virtual projector of scene {:?} is {}x{}, got a {}x{} projector image",
                self.scene.name,
                self.prj.width,
                self.prj.height,
                prj.width(),
                prj.height()
            )));
        }
        Ok(())
    }

    /// Emitted light (linear, projector space, interleaved RGB) for an input image: 8-bit input,
    /// response curves, primaries and black level.
    pub(crate) fn emission(&self, prj: &PrjImage) -> Vec<f32> {
        let src = prj.data();
        par_pixels(src.len() / 3, |i| {
            let px = &src[i * 3..i * 3 + 3];
            let d = [0, 1, 2].map(|c| self.prj_lut[c][level(px[c])]);
            let e = mat3(&self.prj_mix, d);
            [
                e[0] + self.prj_black[0],
                e[1] + self.prj_black[1],
                e[2] + self.prj_black[2],
            ]
        })
    }

    /// Emitted light for linear drives `d` (projector space): M_p·d, plus the black level when
    /// `black` is set.
    pub(crate) fn drive_to_emission(&self, d: &[f32], black: bool) -> Vec<f32> {
        let b = if black { self.prj_black } else { [0.0; 3] };
        let mut out = Vec::with_capacity(d.len());
        for px in d.chunks_exact(3) {
            let e = mat3(&self.prj_mix, [px[0], px[1], px[2]]);
            out.extend_from_slice(&[e[0] + b[0], e[1] + b[1], e[2] + b[2]]);
        }
        out
    }

    /// Adjoint of [`Self::drive_to_emission`] without black level: M_pᵀ per pixel.
    pub(crate) fn emission_to_drive_adjoint(&self, g: &[f32]) -> Vec<f32> {
        let mt = transpose(&self.prj_mix);
        let mut out = Vec::with_capacity(g.len());
        for px in g.chunks_exact(3) {
            out.extend_from_slice(&mat3(&mt, [px[0], px[1], px[2]]));
        }
        out
    }

    /// The linear part of the model: emitted light (projector space) to sensor signal (camera
    /// space), without ambient light and glare.
    pub(crate) fn sensor(&self, emitted: &[f32]) -> Vec<f32> {
        let (pw, ph) = self.projector_size();
        let blurred;
        let e = match &self.defocus {
            Some(k) => {
                blurred = blur_rgb(emitted, pw, ph, k);
                &blurred[..]
            }
            None => emitted,
        };
        let n = self.taps.len();
        let camera = |i: usize, r: [f32; 3]| {
            let s = mat3(&self.cam_mix, r);
            let g = self.gain[i];
            [g * s[0], g * s[1], g * s[2]]
        };
        // Gathered projector light E_i; direct radiance R_i = diffuse_i·E_i + spec_i·E_i.
        let direct = |i: usize| {
            let ei = gather(e, pw, &self.taps[i]);
            let dg = self.diffuse[i];
            let sp = self.spec[i];
            let d = [dg[0] * ei[0], dg[1] * ei[1], dg[2] * ei[2]];
            (d, [d[0] + sp * ei[0], d[1] + sp * ei[1], d[2] + sp * ei[2]])
        };
        let Some(bounce) = &self.bounce else {
            return par_pixels(n, |i| camera(i, direct(i).1));
        };
        // With inter-reflection: the diffuse direct radiance feeds one bounce.
        let diffuse = par_pixels(n, |i| direct(i).0);
        let indirect = bounce.forward(&diffuse);
        par_pixels(n, |i| {
            let r = direct(i).1;
            let a = self.albedo[i];
            let k = &indirect[i * 3..i * 3 + 3];
            camera(
                i,
                [r[0] + a[0] * k[0], r[1] + a[1] * k[1], r[2] + a[2] * k[2]],
            )
        })
    }

    /// Adjoint of [`Self::sensor`]: a camera-space signal gradient to a projector-space
    /// emission gradient.
    pub(crate) fn sensor_adjoint(&self, grad: &[f32]) -> Vec<f32> {
        let (pw, ph) = self.projector_size();
        let n = self.taps.len();
        let mt = transpose(&self.cam_mix);
        // Radiance gradient q_i = gain_i · M_cᵀ · r_i.
        let mut q = Vec::with_capacity(n * 3);
        for i in 0..n {
            let r = mat3(&mt, [grad[i * 3], grad[i * 3 + 1], grad[i * 3 + 2]]);
            let g = self.gain[i];
            q.extend_from_slice(&[g * r[0], g * r[1], g * r[2]]);
        }
        // Gradient with respect to the diffuse direct radiance through the bounce.
        let bounce_grad = self.bounce.as_ref().map(|b| {
            let mut aq = q.clone();
            for i in 0..n {
                for c in 0..3 {
                    aq[i * 3 + c] *= self.albedo[i][c];
                }
            }
            b.adjoint(&aq)
        });
        let mut e = vec![0f32; pw * ph * 3];
        for i in 0..n {
            let dg = self.diffuse[i];
            let sp = self.spec[i];
            let mut ge = [0f32; 3];
            for c in 0..3 {
                let mut dd = q[i * 3 + c];
                if let Some(bg) = &bounce_grad {
                    dd += bg[i * 3 + c];
                }
                ge[c] = dg[c] * dd + sp * q[i * 3 + c];
            }
            scatter(&mut e, pw, &self.taps[i], ge);
        }
        match &self.defocus {
            Some(k) => blur_rgb(&e, pw, ph, k),
            None => e,
        }
    }

    /// Adds ambient light and glare (sensor units) to a sensor signal.
    pub(crate) fn add_constant(&self, s: &mut [f32]) {
        for (px, c) in s.chunks_exact_mut(3).zip(&self.constant) {
            px[0] += c[0];
            px[1] += c[1];
            px[2] += c[2];
        }
    }

    /// Per camera pixel: the sensor signal per unit of gathered projector light in each channel
    /// before camera mixing (ρ·g + spec), the pixel's gain, and the constant term; used by the
    /// oracle's per-pixel inversion.
    pub(crate) fn pixel_terms(&self, i: usize) -> ([f32; 3], f32, [f32; 3]) {
        let d = self.diffuse[i];
        let s = self.spec[i];
        (
            [d[0] + s, d[1] + s, d[2] + s],
            self.gain[i],
            self.constant[i],
        )
    }

    pub(crate) fn cam_mix(&self) -> &[[f32; 3]; 3] {
        &self.cam_mix
    }
    pub(crate) fn prj_mix(&self) -> &[[f32; 3]; 3] {
        &self.prj_mix
    }
    pub(crate) fn prj_black(&self) -> [f32; 3] {
        self.prj_black
    }

    #[inline]
    fn quantise(&self, s: f32) -> u8 {
        if s.is_nan() || s <= 0.0 {
            return 0;
        }
        if s >= 1.0 {
            return 255;
        }
        let b = ((s * QUANT_BUCKETS as f32) as i32 as usize).min(QUANT_BUCKETS - 1);
        let mut q = self.bucket_level[b] as usize;
        while q < 255 && self.thresholds[q] <= s {
            q += 1;
        }
        q as u8
    }
}

/// Everything the simulator keeps for one camera pixel.
struct PixelMaps {
    tap: Tap,
    prj_xy: [f32; 2],
    lit: bool,
    shadow: bool,
    diffuse: [f32; 3],
    spec: f32,
    albedo: [f32; 3],
    gain: f32,
    constant: [f32; 3],
    preview: [f32; 3],
}

struct PixelCtx<'a> {
    cam: &'a Pinhole,
    prj: &'a Pinhole,
    shape: &'a Shape,
    albedo: &'a AlbedoField,
    scene: &'a Scene,
    d_ref: f64,
    cam_mix: [[f32; 3]; 3],
    amb_dir: (f64, f64),
}

impl PixelCtx<'_> {
    fn pixel(&self, x: usize, y: usize) -> PixelMaps {
        let sc = self.scene;
        let (xf, yf) = (x as f64, y as f64);
        let gain =
            (sc.camera.exposure * (1.0 - sc.camera.vignetting * self.cam.radius2(xf, yf))) as f32;
        let mut px = PixelMaps {
            tap: Tap::default(),
            prj_xy: [f32::NAN; 2],
            lit: false,
            shadow: false,
            diffuse: [0.0; 3],
            spec: 0.0,
            albedo: [0.0; 3],
            gain,
            constant: [0.0; 3],
            preview: [0.0; 3],
        };
        let dir = self.cam.ray(xf, yf);
        let Some(t) = self.shape.intersect(&self.cam.centre, &dir) else {
            return px;
        };
        let p = self.cam.centre + dir * t;
        let n = self.shape.normal(&p);
        let rho = self.albedo.at(p.x, p.y);
        px.albedo = rho.map(|v| v as f32);
        let view = (self.cam.centre - p).normalize();

        // Ambient irradiance (offset + tinted ramp across the camera view) and glare.
        let amb = &sc.ambient;
        let (xn, yn) = (
            (xf - self.cam.cx) / (self.cam.cx + 0.5),
            (yf - self.cam.cy) / (self.cam.cy + 0.5),
        );
        let ramp = (0.5 + 0.5 * (self.amb_dir.0 * xn + self.amb_dir.1 * yn)).clamp(0.0, 1.0);
        let mut radiance_const: [f64; 3] =
            [0, 1, 2].map(|c| rho[c] * (amb.offset[c] + amb.gradient[c] * ramp));
        if let Some(gl) = &sc.glare {
            let (w, h) = (self.cam.width as f64, self.cam.height as f64);
            let (dx, dy) = (xf - gl.centre[0] * w, yf - gl.centre[1] * h);
            let r = gl.radius * w;
            let k = (-(dx * dx + dy * dy) / (2.0 * r * r)).exp();
            for (r, g) in radiance_const.iter_mut().zip(gl.rgb) {
                *r += g * k;
            }
        }
        let s = mat3(&self.cam_mix, radiance_const.map(|v| v as f32));
        px.constant = s.map(|v| v * gain);

        // Projector light.
        let to_prj = self.prj.centre - p;
        let dist = to_prj.norm();
        let l = to_prj / dist;
        let cos_in = n.dot(&l);
        let (pw, ph) = (self.prj.width as f64, self.prj.height as f64);
        let mut lit = false;
        if let Some((u, v)) = self.prj.project(&p) {
            let in_frustum = u > -1.0 && v > -1.0 && u < pw && v < ph;
            if in_frustum {
                let reached = cos_in > 0.0 && self.shape.reaches(&self.prj.centre, &p);
                if reached {
                    px.prj_xy = [u as f32, v as f32];
                    px.tap = tap(u, v, self.prj.width, self.prj.height);
                    lit = u >= -0.5 && v >= -0.5 && u <= pw - 0.5 && v <= ph - 0.5;
                    let falloff = (self.d_ref / dist).powi(2);
                    let vig = 1.0 - sc.projector.vignetting * self.prj.radius2(u, v).min(1.5);
                    let g = cos_in * falloff * vig;
                    px.diffuse = rho.map(|r| (r * g) as f32);
                    if let Some(spec) = &sc.specular {
                        let half = (l + view).normalize();
                        let nh = n.dot(&half).max(0.0);
                        px.spec = (spec.strength * nh.powf(spec.shininess) * falloff * vig) as f32;
                    }
                } else {
                    // In the frame's frustum but hidden from the projector (or facing away).
                    px.shadow = u >= -0.5 && v >= -0.5 && u <= pw - 0.5 && v <= ph - 0.5;
                }
            }
        }
        px.lit = lit;

        // Preview under neutral room light from the camera side.
        let shade = 0.25 + 0.75 * n.dot(&view).max(0.0);
        let dim = if lit { 1.0 } else { 0.45 };
        px.preview = rho.map(|r| ((r * shade * 0.9).powf(1.0 / 2.2) * dim) as f32);
        px
    }
}

fn surface_distance(s: &Surface) -> f64 {
    match s {
        Surface::Plane { distance, .. }
        | Surface::Cylinder { distance, .. }
        | Surface::Wave { distance, .. }
        | Surface::Corner { distance, .. }
        | Surface::Step { distance, .. } => *distance,
    }
}

/// Bilinear taps at projector coordinate (u, v) with zeros outside the w×h frame. The base is
/// kept inside [0, w−2]×[0, h−2] and out-of-frame taps get weight zero.
fn tap(u: f64, v: f64, w: usize, h: usize) -> Tap {
    let axis = |c: f64, n: usize| -> (usize, [f32; 2]) {
        let c0 = c.floor();
        let f = (c - c0) as f32;
        let i0 = c0 as isize;
        // Weights of pixels i0 and i0+1, dropping those outside [0, n−1].
        let w0 = if i0 >= 0 && i0 < n as isize {
            1.0 - f
        } else {
            0.0
        };
        let w1 = if i0 + 1 >= 0 && i0 + 1 < n as isize {
            f
        } else {
            0.0
        };
        if i0 < 0 {
            // Pixel 0 gets w1 and sits at the base.
            (0, [w1, 0.0])
        } else if i0 as usize >= n - 1 {
            // Pixel n−1 gets w0 and sits one after the base.
            (n - 2, [0.0, w0])
        } else {
            (i0 as usize, [w0, w1])
        }
    };
    let (bx, wx) = axis(u, w);
    let (by, wy) = axis(v, h);
    Tap {
        base: (by * w + bx) as u32,
        w: [wx[0] * wy[0], wx[1] * wy[0], wx[0] * wy[1], wx[1] * wy[1]],
    }
}

#[inline]
fn gather(e: &[f32], w: usize, t: &Tap) -> [f32; 3] {
    let b = t.base as usize * 3;
    let r = b + w * 3;
    let mut out = [0f32; 3];
    for (c, o) in out.iter_mut().enumerate() {
        *o = t.w[0] * e[b + c] + t.w[1] * e[b + 3 + c] + t.w[2] * e[r + c] + t.w[3] * e[r + 3 + c];
    }
    out
}

#[inline]
fn scatter(e: &mut [f32], w: usize, t: &Tap, g: [f32; 3]) {
    if t.w == [0.0; 4] {
        return;
    }
    let b = t.base as usize * 3;
    let r = b + w * 3;
    for (c, &gc) in g.iter().enumerate() {
        e[b + c] += t.w[0] * gc;
        e[b + 3 + c] += t.w[1] * gc;
        e[r + c] += t.w[2] * gc;
        e[r + 3 + c] += t.w[3] * gc;
    }
}

#[inline]
pub(crate) fn mat3(m: &[[f32; 3]; 3], v: [f32; 3]) -> [f32; 3] {
    [
        m[0][0] * v[0] + m[0][1] * v[1] + m[0][2] * v[2],
        m[1][0] * v[0] + m[1][1] * v[1] + m[1][2] * v[2],
        m[2][0] * v[0] + m[2][1] * v[1] + m[2][2] * v[2],
    ]
}

pub(crate) fn transpose(m: &[[f32; 3]; 3]) -> [[f32; 3]; 3] {
    [
        [m[0][0], m[1][0], m[2][0]],
        [m[0][1], m[1][1], m[2][1]],
        [m[0][2], m[1][2], m[2][2]],
    ]
}

/// Normalised Gaussian taps, radius ⌈3σ⌉.
fn gaussian_kernel(sigma: f64) -> Vec<f32> {
    let r = (3.0 * sigma).ceil().max(1.0) as isize;
    let taps: Vec<f64> = (-r..=r)
        .map(|i| (-(i * i) as f64 / (2.0 * sigma * sigma)).exp())
        .collect();
    let sum: f64 = taps.iter().sum();
    taps.into_iter().map(|t| (t / sum) as f32).collect()
}

/// Separable blur of an interleaved RGB image with an odd symmetric kernel and zero padding.
/// Being a symmetric operator with zero padding, it is its own adjoint.
pub(crate) fn blur_rgb(src: &[f32], w: usize, h: usize, kernel: &[f32]) -> Vec<f32> {
    let r = kernel.len() / 2;
    let row = w * 3;
    // Horizontal: out[i] += k·src[i + 3·(t − r)] over the valid range of each row.
    let mut tmp = vec![0f32; src.len()];
    tmp.par_chunks_mut(row)
        .zip(src.par_chunks(row))
        .for_each(|(o, s)| {
            for (t, &k) in kernel.iter().enumerate() {
                let off = t as isize - r as isize;
                let shift = off.unsigned_abs() * 3;
                if shift >= row {
                    continue;
                }
                if off >= 0 {
                    for (a, b) in o[..row - shift].iter_mut().zip(&s[shift..]) {
                        *a += k * b;
                    }
                } else {
                    for (a, b) in o[shift..].iter_mut().zip(&s[..row - shift]) {
                        *a += k * b;
                    }
                }
            }
        });
    // Vertical: output row y += k·tmp row (y + t − r).
    let mut out = vec![0f32; src.len()];
    out.par_chunks_mut(row).enumerate().for_each(|(y, o)| {
        for (t, &k) in kernel.iter().enumerate() {
            let yy = y as isize + t as isize - r as isize;
            if yy < 0 || yy >= h as isize {
                continue;
            }
            let s = &tmp[yy as usize * row..(yy as usize + 1) * row];
            for (a, b) in o.iter_mut().zip(s) {
                *a += k * b;
            }
        }
    });
    out
}

/// Pixels per parallel work item.
const CHUNK: usize = 4096;

/// `f(i)` for every pixel i < n as interleaved RGB, computed in parallel (the result does not
/// depend on the number of threads).
fn par_pixels(n: usize, f: impl Fn(usize) -> [f32; 3] + Sync) -> Vec<f32> {
    let mut out = vec![0f32; n * 3];
    out.par_chunks_mut(CHUNK * 3)
        .enumerate()
        .for_each(|(c, chunk)| {
            for (j, px) in chunk.chunks_exact_mut(3).enumerate() {
                px.copy_from_slice(&f(c * CHUNK + j));
            }
        });
    out
}

/// The 8-bit level a projector shows for input value `v` (round to nearest, clamped; NaN → 0),
/// as [`crate::pngio::to_u8`] but without a call to `round`.
#[inline]
fn level(v: f32) -> usize {
    // Through i32: the saturating float-to-i32 conversion is much cheaper than to usize.
    (v.clamp(0.0, 1.0) * 255.0 + 0.5) as i32 as usize
}

impl Bounce {
    fn new(w: usize, h: usize, strength: f64, radius: f64) -> Self {
        let block = (w / 80).max(1);
        let (cw, ch) = (w.div_ceil(block), h.div_ceil(block));
        let sigma = (radius * w as f64 / block as f64).max(0.5);
        let taps = |n: usize, nc: usize| -> Vec<(usize, usize, f32)> {
            (0..n)
                .map(|i| {
                    let c = ((i as f64 + 0.5) / block as f64 - 0.5).clamp(0.0, (nc - 1) as f64);
                    let i0 = (c.floor() as usize).min(nc - 1);
                    let i1 = (i0 + 1).min(nc - 1);
                    (i0, i1, (c - i0 as f64) as f32)
                })
                .collect()
        };
        Bounce {
            strength: strength as f32,
            block,
            cw,
            ch,
            kernel: gaussian_kernel(sigma),
            xtaps: taps(w, cw),
            ytaps: taps(h, ch),
        }
    }

    /// Fine (camera) pixels in coarse block (bx, by).
    fn block_count(&self, w: usize, h: usize, bx: usize, by: usize) -> f32 {
        let bw = (w - bx * self.block).min(self.block);
        let bh = (h - by * self.block).min(self.block);
        (bw * bh) as f32
    }

    /// Indirect irradiance: strength × upsample(blur(box-average(direct))).
    fn forward(&self, direct: &[f32]) -> Vec<f32> {
        let (w, h) = (self.xtaps.len(), self.ytaps.len());
        let mut coarse = vec![0f32; self.cw * self.ch * 3];
        for y in 0..h {
            for x in 0..w {
                let ci = ((y / self.block) * self.cw + x / self.block) * 3;
                for c in 0..3 {
                    coarse[ci + c] += direct[(y * w + x) * 3 + c];
                }
            }
        }
        for by in 0..self.ch {
            for bx in 0..self.cw {
                let k = 1.0 / self.block_count(w, h, bx, by);
                for c in 0..3 {
                    coarse[(by * self.cw + bx) * 3 + c] *= k;
                }
            }
        }
        let blurred = blur_rgb(&coarse, self.cw, self.ch, &self.kernel);
        let mut out = vec![0f32; w * h * 3];
        for (y, &(y0, y1, fy)) in self.ytaps.iter().enumerate() {
            for (x, &(x0, x1, fx)) in self.xtaps.iter().enumerate() {
                for c in 0..3 {
                    let at = |yy: usize, xx: usize| blurred[(yy * self.cw + xx) * 3 + c];
                    let v = (1.0 - fy) * ((1.0 - fx) * at(y0, x0) + fx * at(y0, x1))
                        + fy * ((1.0 - fx) * at(y1, x0) + fx * at(y1, x1));
                    out[(y * w + x) * 3 + c] = self.strength * v;
                }
            }
        }
        out
    }

    /// Adjoint of [`Bounce::forward`].
    fn adjoint(&self, grad: &[f32]) -> Vec<f32> {
        let (w, h) = (self.xtaps.len(), self.ytaps.len());
        let mut coarse = vec![0f32; self.cw * self.ch * 3];
        for (y, &(y0, y1, fy)) in self.ytaps.iter().enumerate() {
            for (x, &(x0, x1, fx)) in self.xtaps.iter().enumerate() {
                for c in 0..3 {
                    let g = self.strength * grad[(y * w + x) * 3 + c];
                    coarse[(y0 * self.cw + x0) * 3 + c] += (1.0 - fy) * (1.0 - fx) * g;
                    coarse[(y0 * self.cw + x1) * 3 + c] += (1.0 - fy) * fx * g;
                    coarse[(y1 * self.cw + x0) * 3 + c] += fy * (1.0 - fx) * g;
                    coarse[(y1 * self.cw + x1) * 3 + c] += fy * fx * g;
                }
            }
        }
        let blurred = blur_rgb(&coarse, self.cw, self.ch, &self.kernel);
        let mut out = vec![0f32; w * h * 3];
        for y in 0..h {
            for x in 0..w {
                let (bx, by) = (x / self.block, y / self.block);
                let k = 1.0 / self.block_count(w, h, bx, by);
                for c in 0..3 {
                    out[(y * w + x) * 3 + c] = k * blurred[(by * self.cw + bx) * 3 + c];
                }
            }
        }
        out
    }
}

/// Runs `f` for every row in 0..h on the available cores and concatenates the results in row
/// order (the output does not depend on the number of threads).
pub(crate) fn par_rows<T: Send>(h: usize, f: impl Fn(usize) -> Vec<T> + Sync) -> Vec<T> {
    let threads = std::thread::available_parallelism()
        .map(|n| n.get())
        .unwrap_or(1)
        .clamp(1, 16);
    if threads == 1 || h < 8 {
        return (0..h).flat_map(&f).collect();
    }
    let chunk = h.div_ceil(threads);
    let f = &f;
    std::thread::scope(|s| {
        let handles: Vec<_> = (0..h)
            .step_by(chunk)
            .map(|start| {
                s.spawn(move || {
                    (start..(start + chunk).min(h))
                        .flat_map(f)
                        .collect::<Vec<T>>()
                })
            })
            .collect();
        handles
            .into_iter()
            .flat_map(|hd| hd.join().expect("a simulator worker thread panicked"))
            .collect()
    })
}

/// SplitMix64 finaliser: a bijective 64-bit hash (value-stable, platform-independent).
#[inline]
pub(crate) fn mix64(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// An approximately standard normal value from 64 random bits: the sum of four 16-bit uniforms
/// (Irwin–Hall), centred and scaled to unit variance. Tails end at ±3.46σ.
#[inline]
fn approx_normal(bits: u64) -> f32 {
    let u = |k: u32| ((bits >> (16 * k)) & 0xffff) as f32 + 0.5;
    let sum = (u(0) + u(1) + u(2) + u(3)) / 65536.0;
    (sum - 2.0) * 3f32.sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn taps_read_zeros_outside_and_sum_to_one_inside() {
        let t = tap(2.25, 1.5, 5, 4);
        assert_eq!(t.base, 5 + 2);
        assert!((t.w.iter().sum::<f32>() - 1.0).abs() < 1e-6);
        // Half a pixel left of the first column: half the weight is lost to the outside.
        let t = tap(-0.5, 0.0, 5, 4);
        assert_eq!(t.base, 0);
        assert!((t.w.iter().sum::<f32>() - 0.5).abs() < 1e-6);
        assert!((t.w[0] - 0.5).abs() < 1e-6);
        // Half a pixel past the last row and column.
        let t = tap(4.5, 3.5, 5, 4);
        assert_eq!(t.base as usize, 2 * 5 + 3);
        assert!((t.w[3] - 0.25).abs() < 1e-6 && t.w[0] == 0.0);
        // Exactly on the last pixel centre.
        let t = tap(4.0, 3.0, 5, 4);
        assert!((t.w[3] - 1.0).abs() < 1e-6);
    }

    #[test]
    fn blur_is_self_adjoint_and_bounce_adjoint_matches() {
        let (w, h) = (13, 9);
        let a: Vec<f32> = (0..w * h * 3)
            .map(|i| ((i * 37 % 101) as f32) / 101.0)
            .collect();
        let b: Vec<f32> = (0..w * h * 3)
            .map(|i| ((i * 53 % 97) as f32) / 97.0)
            .collect();
        let k = gaussian_kernel(1.7);
        let dot = |x: &[f32], y: &[f32]| x.iter().zip(y).map(|(p, q)| (p * q) as f64).sum::<f64>();
        let lhs = dot(&blur_rgb(&a, w, h, &k), &b);
        let rhs = dot(&a, &blur_rgb(&b, w, h, &k));
        assert!((lhs - rhs).abs() < 1e-4 * lhs.abs(), "{lhs} {rhs}");

        let (w, h) = (170, 45);
        let bounce = Bounce::new(w, h, 0.3, 0.1);
        assert!(bounce.block >= 2, "exercise partial blocks");
        let a: Vec<f32> = (0..w * h * 3)
            .map(|i| ((i * 37 % 101) as f32) / 101.0)
            .collect();
        let b: Vec<f32> = (0..w * h * 3)
            .map(|i| ((i * 53 % 97) as f32) / 97.0)
            .collect();
        let lhs = dot(&bounce.forward(&a), &b);
        let rhs = dot(&a, &bounce.adjoint(&b));
        assert!((lhs - rhs).abs() < 1e-4 * lhs.abs(), "{lhs} {rhs}");
    }

    #[test]
    fn sensor_adjoint_matches_forward() {
        // Every linear stage at once: defocus, specular, inter-reflection, colour mixing.
        let mut scene = crate::rig::builtin("specular-corner")
            .expect("built-in")
            .with_resolution((90, 50), (70, 52));
        scene.projector.defocus_px = 1.3;
        let sim = Simulator::new(&scene, 3, Phase::Calibration).expect("builds");
        let (pw, ph) = sim.projector_size();
        let (cw, ch) = sim.camera_size();
        let a: Vec<f32> = (0..pw * ph * 3)
            .map(|i| ((i * 37 % 101) as f32) / 101.0)
            .collect();
        let b: Vec<f32> = (0..cw * ch * 3)
            .map(|i| ((i * 53 % 97) as f32) / 97.0)
            .collect();
        let dot = |x: &[f32], y: &[f32]| x.iter().zip(y).map(|(p, q)| (p * q) as f64).sum::<f64>();
        let fwd = sim.sensor(&sim.drive_to_emission(&a, false));
        let adj = sim.emission_to_drive_adjoint(&sim.sensor_adjoint(&b));
        let (lhs, rhs) = (dot(&fwd, &b), dot(&a, &adj));
        assert!(lhs > 1.0, "the scene is lit: {lhs}");
        assert!((lhs - rhs).abs() < 1e-4 * lhs, "{lhs} vs {rhs}");
    }

    #[test]
    fn approx_normal_has_unit_variance() {
        let n = 200_000;
        let v: Vec<f64> = (0..n).map(|i| approx_normal(mix64(i)) as f64).collect();
        let mean = v.iter().sum::<f64>() / n as f64;
        let var = v.iter().map(|x| (x - mean) * (x - mean)).sum::<f64>() / n as f64;
        assert!(mean.abs() < 0.01, "mean {mean}");
        assert!((var - 1.0).abs() < 0.02, "var {var}");
    }
}
