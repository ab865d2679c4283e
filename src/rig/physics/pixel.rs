//! The per-camera-pixel maps of the simulator: ray casting from the camera, shading, ambient
//! light, glare, and the bilinear taps into the projector frame.
//!
//! Spaces: `x`, `y` are camera pixels; projector coordinates `(u, v)` are projector pixels with
//! centres at integers; world positions are metres (see [`super::super::scene`]).

use super::Tap;
use super::kernels::{mat3, par_rows};
use crate::rig::geom::{Pinhole, Shape};
use crate::rig::scene::{Scene, Surface};
use crate::rig::texture::AlbedoField;

/// The per-pixel maps of every camera pixel (row-major) of `scene` seen by `cam`, lit by `prj`.
pub(super) fn camera_maps(
    scene: &Scene,
    seed: u64,
    cam: &Pinhole,
    prj: &Pinhole,
    shape: &Shape,
    cam_mix: [[f32; 3]; 3],
) -> Vec<PixelMaps> {
    let c = &scene.camera;
    let albedo_field = AlbedoField::new(&scene.albedo, seed);

    // Reference distance for the fall-off: along the projector's optical axis to the surface.
    let axis = prj.ray(prj.cx, prj.cy);
    let d_ref = shape
        .intersect(&prj.centre, &axis)
        .map(|t| t * axis.norm())
        .unwrap_or_else(|| surface_distance(&scene.surface));
    let (cw, chh) = (c.width, c.height);
    let amb = &scene.ambient;
    let amb_dir = amb.direction_deg.to_radians();

    let ctx = PixelCtx {
        cam,
        prj,
        shape,
        albedo: &albedo_field,
        scene,
        d_ref,
        cam_mix,
        amb_dir: (amb_dir.cos(), amb_dir.sin()),
    };
    par_rows(chh, |y| {
        (0..cw).map(|x| ctx.pixel(x, y)).collect::<Vec<_>>()
    })
}

/// Everything the simulator keeps for one camera pixel.
pub(super) struct PixelMaps {
    pub(super) tap: Tap,
    pub(super) prj_xy: [f32; 2],
    pub(super) lit: bool,
    pub(super) shadow: bool,
    pub(super) diffuse: [f32; 3],
    pub(super) spec: f32,
    pub(super) albedo: [f32; 3],
    pub(super) gain: f32,
    pub(super) constant: [f32; 3],
    pub(super) preview: [f32; 3],
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
pub(super) fn tap(u: f64, v: f64, w: usize, h: usize) -> Tap {
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
