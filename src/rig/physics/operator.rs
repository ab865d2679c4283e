//! The linear part of the simulator's forward model (steps 1–4 of [`super`] between the
//! projector's response curve and the sensor signal, without noise) and its adjoint, as the oracle
//! ([`super::super::oracle`]) needs them.
//!
//! Spaces: drives and emitted light are projector images (projector pixels, interleaved linear
//! RGB); sensor signals are camera images (camera pixels, interleaved linear RGB, not clipped).

use super::kernels::{blur_rgb, level, mat3, par_pixels, transpose};
use super::{Simulator, Tap};
use crate::raster::{ImageSize, PrjImage};
use crate::rig::scene::LcdCrosstalk;

/// The constants of an LCD projector's cross-talk ([`LcdCrosstalk`]) per entry (i, j) of the
/// mixing, off the diagonal (the diagonal's are unused): the leak's share at black relative to
/// full drive, k², and its relative change per unit of the frame position u (−1 left column,
/// +1 right).
#[derive(Clone, Copy, Debug)]
pub(crate) struct LcdTerms {
    k2: [[f32; 3]; 3],
    tilt: [[f32; 3]; 3],
}

impl LcdTerms {
    pub(crate) fn new(lcd: &LcdCrosstalk) -> Self {
        // Channel i below panel j in the matrix (i > j: red, green, blue) is at shorter
        // wavelengths: panel j's short edge leaks into it.
        let towards_short = |i: usize, j: usize| i > j;
        Self {
            k2: std::array::from_fn(|i| {
                std::array::from_fn(|j| {
                    let k = if towards_short(i, j) {
                        1.0 / (1.0 - lcd.edge_offset)
                    } else {
                        1.0 / (1.0 + lcd.edge_offset)
                    };
                    (k * k) as f32
                })
            }),
            tilt: std::array::from_fn(|i| {
                std::array::from_fn(|j| {
                    (if towards_short(i, j) {
                        lcd.across
                    } else {
                        -lcd.across
                    }) as f32
                })
            }),
        }
    }

    /// The mixing at drives `d` and frame position `u` such that e = that matrix · d: the
    /// off-diagonal entries scaled by (1 + tilt·u)·(k² + (1 − k²)·d_j).
    #[inline]
    fn mixing(&self, m: &[[f32; 3]; 3], d: [f32; 3], u: f32) -> [[f32; 3]; 3] {
        self.off_diagonal(m, d, u, |k2, dj| k2 + (1.0 - k2) * dj)
    }

    /// The Jacobian of e(d) = [`Self::mixing`]·d at `d`: off the diagonal
    /// M_ij·(1 + tilt·u)·(k² + 2(1 − k²)·d_j).
    #[inline]
    fn jacobian(&self, m: &[[f32; 3]; 3], d: [f32; 3], u: f32) -> [[f32; 3]; 3] {
        self.off_diagonal(m, d, u, |k2, dj| k2 + 2.0 * (1.0 - k2) * dj)
    }

    /// `m` with each off-diagonal entry (i, j) scaled by (1 + tilt·u)·`level`(k², d_j).
    #[inline]
    fn off_diagonal(
        &self,
        m: &[[f32; 3]; 3],
        d: [f32; 3],
        u: f32,
        level: impl Fn(f32, f32) -> f32,
    ) -> [[f32; 3]; 3] {
        std::array::from_fn(|i| {
            std::array::from_fn(|j| {
                if i == j {
                    m[i][j]
                } else {
                    m[i][j] * (1.0 + self.tilt[i][j] * u) * level(self.k2[i][j], d[j])
                }
            })
        })
    }
}

impl Simulator {
    /// Emitted light (linear, projector space, interleaved RGB) for an input image: 8-bit input,
    /// response curves, primaries and black level.
    pub(crate) fn emission(&self, prj: &PrjImage) -> Vec<f32> {
        let src = prj.data();
        par_pixels(src.len() / 3, |i| {
            let px = &src[i * 3..i * 3 + 3];
            let d = [0, 1, 2].map(|c| self.prj_lut[c][level(px[c])]);
            let e = self.emit(d, self.frame_u(i));
            [
                e[0] + self.prj_black[0],
                e[1] + self.prj_black[1],
                e[2] + self.prj_black[2],
            ]
        })
    }

    /// The horizontal frame position of projector pixel `i` (row-major): −1 at the left edge of
    /// the frame, +1 at the right.
    #[inline]
    fn frame_u(&self, i: usize) -> f32 {
        let pw = self.projector_size().width;
        2.0 * ((i % pw) as f32 + 0.5) / pw as f32 - 1.0
    }

    /// Light emitted for drives `d` of one pixel at frame position `u`, without black:
    /// M_p·d + w·min(d), M_p the LCD's level- and position-dependent mixing where it has one.
    #[inline]
    fn emit(&self, d: [f32; 3], u: f32) -> [f32; 3] {
        let e = match &self.prj_lcd {
            Some(lcd) => mat3(&lcd.mixing(&self.prj_mix, d, u), d),
            None => mat3(&self.prj_mix, d),
        };
        let m = d[0].min(d[1]).min(d[2]);
        let w = self.prj_white;
        [e[0] + w[0] * m, e[1] + w[1] * m, e[2] + w[2] * m]
    }

    /// Emitted light for linear drives `d` (projector pixels, row-major from the first):
    /// M_p·d + w·min(d), plus the black level when `black` is set.
    pub(crate) fn drive_to_emission(&self, d: &[f32], black: bool) -> Vec<f32> {
        let b = if black { self.prj_black } else { [0.0; 3] };
        let mut out = Vec::with_capacity(d.len());
        for (i, px) in d.chunks_exact(3).enumerate() {
            let e = self.emit([px[0], px[1], px[2]], self.frame_u(i));
            out.extend_from_slice(&[e[0] + b[0], e[1] + b[1], e[2] + b[2]]);
        }
        out
    }

    /// Adjoint of the Jacobian of [`Self::drive_to_emission`] at drives `d`: M_pᵀ per pixel
    /// (the LCD's Jacobian where it has one), plus wᵀg on the channel of the smallest drive
    /// (the first of equals). Without an LCD's cross-talk the Jacobian at `d` reproduces the
    /// map at `d` (it is piecewise linear and positively homogeneous).
    pub(crate) fn emission_to_drive_adjoint(&self, d: &[f32], g: &[f32]) -> Vec<f32> {
        let mt = transpose(&self.prj_mix);
        let w = self.prj_white;
        let mut out = Vec::with_capacity(g.len());
        for (i, (px, dp)) in g.chunks_exact(3).zip(d.chunks_exact(3)).enumerate() {
            let mut a = match &self.prj_lcd {
                Some(lcd) => mat3(
                    &transpose(&lcd.jacobian(
                        &self.prj_mix,
                        [dp[0], dp[1], dp[2]],
                        self.frame_u(i),
                    )),
                    [px[0], px[1], px[2]],
                ),
                None => mat3(&mt, [px[0], px[1], px[2]]),
            };
            if w != [0.0; 3] {
                let k = if dp[0] <= dp[1] && dp[0] <= dp[2] {
                    0
                } else if dp[1] <= dp[2] {
                    1
                } else {
                    2
                };
                a[k] += w[0] * px[0] + w[1] * px[1] + w[2] * px[2];
            }
            out.extend_from_slice(&a);
        }
        out
    }

    /// The linear part of the model: emitted light (projector space) to sensor signal (camera
    /// space), without ambient light and glare.
    pub(crate) fn sensor(&self, emitted: &[f32]) -> Vec<f32> {
        let ImageSize {
            width: pw,
            height: ph,
        } = self.projector_size();
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
        // With sub-surface scattering, the diffuse radiance of every pixel first.
        let spread = self
            .subsurface
            .as_ref()
            .map(|ss| ss.forward(&par_pixels(n, |i| gather(e, pw, &self.taps[i]))));
        // Gathered projector light E_i; direct radiance R_i = diffuse_i·E_i + spec_i·E_i.
        let direct = |i: usize| {
            let ei = gather(e, pw, &self.taps[i]);
            let dg = self.diffuse[i];
            let sp = self.spec[i];
            let d = match &spread {
                Some(v) => [v[i * 3], v[i * 3 + 1], v[i * 3 + 2]],
                None => [dg[0] * ei[0], dg[1] * ei[1], dg[2] * ei[2]],
            };
            (d, [d[0] + sp * ei[0], d[1] + sp * ei[1], d[2] + sp * ei[2]])
        };
        let blur = |s: Vec<f32>| match &self.cam_blur {
            Some(k) => {
                let ImageSize {
                    width: cw,
                    height: ch,
                } = self.camera_size();
                blur_rgb(&s, cw, ch, k)
            }
            None => s,
        };
        let Some(bounce) = &self.bounce else {
            return blur(par_pixels(n, |i| camera(i, direct(i).1)));
        };
        // With inter-reflection: the diffuse direct radiance feeds one bounce.
        let diffuse = par_pixels(n, |i| direct(i).0);
        let indirect = bounce.forward(&diffuse);
        blur(par_pixels(n, |i| {
            let r = direct(i).1;
            let a = self.albedo[i];
            let k = &indirect[i * 3..i * 3 + 3];
            camera(
                i,
                [r[0] + a[0] * k[0], r[1] + a[1] * k[1], r[2] + a[2] * k[2]],
            )
        }))
    }

    /// Adjoint of [`Self::sensor`]: a camera-space signal gradient to a projector-space
    /// emission gradient.
    pub(crate) fn sensor_adjoint(&self, grad: &[f32]) -> Vec<f32> {
        let ImageSize {
            width: pw,
            height: ph,
        } = self.projector_size();
        let n = self.taps.len();
        let mt = transpose(&self.cam_mix);
        // The optics' blur is its own adjoint (symmetric kernel, zero padding).
        let blurred;
        let grad = match &self.cam_blur {
            Some(k) => {
                let ImageSize {
                    width: cw,
                    height: ch,
                } = self.camera_size();
                blurred = blur_rgb(grad, cw, ch, k);
                &blurred[..]
            }
            None => grad,
        };
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
        // With sub-surface scattering: the gathered-light gradient of the diffuse radiance.
        let spread = self.subsurface.as_ref().map(|ss| {
            let mut dd = q.clone();
            if let Some(bg) = &bounce_grad {
                for (a, b) in dd.iter_mut().zip(bg) {
                    *a += b;
                }
            }
            ss.adjoint(&dd)
        });
        let mut e = vec![0f32; pw * ph * 3];
        for i in 0..n {
            let dg = self.diffuse[i];
            let sp = self.spec[i];
            let mut ge = [0f32; 3];
            for c in 0..3 {
                let diffuse = match &spread {
                    Some(v) => v[i * 3 + c],
                    None => {
                        let mut dd = q[i * 3 + c];
                        if let Some(bg) = &bounce_grad {
                            dd += bg[i * 3 + c];
                        }
                        dg[c] * dd
                    }
                };
                ge[c] = diffuse + sp * q[i * 3 + c];
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

    /// Adds `light` (sensor units, camera pixels, interleaved RGB) to the constant term: light
    /// that reaches the camera whatever this projector shows (another projector's black).
    pub(crate) fn add_to_constant(&mut self, light: &[f32]) {
        for (c, px) in self.constant.iter_mut().zip(light.chunks_exact(3)) {
            c[0] += px[0];
            c[1] += px[1];
            c[2] += px[2];
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
