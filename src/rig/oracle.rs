//! Reference projector images that know the scene's true model: the geometry-only warp and the
//! oracle (the physical ceiling of compensation under input clipping).

use super::physics::{SetSimulator, Simulator, mat3};
use crate::error::{Error, Result};
use crate::raster::{CamImage, Camera, ImageSize, Mask, PrjImage, check_same_size};

/// Settings of the oracle's solver.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OracleOptions {
    /// Iterations of accelerated projected gradient after the per-pixel start.
    pub iterations: usize,
}

impl Default for OracleOptions {
    fn default() -> Self {
        OracleOptions { iterations: 60 }
    }
}

impl Simulator {
    /// The desired camera image warped into projector space through the true geometry, with no
    /// colour correction: each projector pixel shows the desired value at the camera pixel where
    /// its light lands (bilinear, zeros outside the camera frame; black where no camera pixel
    /// sees it).
    pub fn geometry_only(&self, desired: &CamImage) -> Result<PrjImage> {
        self.check_cam(desired, "the desired image")?;
        let ImageSize {
            width: pw,
            height: ph,
        } = self.projector_size();
        let coords = self.camera_coords();
        let mut data = Vec::with_capacity(pw * ph * 3);
        for xy in coords {
            data.extend_from_slice(&sample_cam(desired.data(), desired.size(), *xy));
        }
        PrjImage::from_vec(pw, ph, data)
    }

    /// The best projector image for `desired` that the true (noise-free) model allows: it
    /// minimises the squared error of the camera's encoded output (after clipping and the
    /// response curve, before quantisation) against `desired` over the camera pixels in `mask`,
    /// subject to projector inputs in \[0,1\]. Defocus, inter-reflection, colour mixing and the
    /// many-to-one mapping between camera and projector pixels are all part of the model it
    /// inverts.
    ///
    /// Method: per-pixel inversion of the local model in camera space, warped to projector
    /// space through the true geometry, then projected gradient descent on the linear drives
    /// (the model is linear in them up to the camera's clip and response curve), scaled per
    /// projector pixel by the diagonal diag(AᵀWA·1) of a Gauss-Newton majoriser (W the squared
    /// slope of the response at the current output), with step halving whenever the objective
    /// would rise: the result is never worse than the per-pixel start.
    pub fn oracle(
        &self,
        desired: &CamImage,
        mask: &Mask<Camera>,
        opts: OracleOptions,
    ) -> Result<PrjImage> {
        self.check_cam(desired, "the desired image")?;
        let (z, gamma_c) = (desired.data(), self.scene().camera.gamma as f32);
        let (inside, target) = masked_target(desired, mask, gamma_c)?;

        // Constant part c = A(black) + ambient + glare.
        let ImageSize {
            width: pw,
            height: ph,
        } = self.projector_size();
        let zeros = vec![0f32; pw * ph * 3];
        let mut c = self.sensor(&self.drive_to_emission(&zeros, true));
        self.add_constant(&mut c);
        let problem = Objective {
            sims: vec![self],
            z,
            inside,
            c,
            gamma_c,
        };
        let ones = vec![1f32; pw * ph * 3];
        let a1 = self.sensor(&self.drive_to_emission(&ones, false));

        let x = self.per_pixel_start(&target, mask)?;
        let x = problem.descend(x, &a1, opts.iterations);

        self.input_levels(x)
    }

    /// Linear drives (projector pixels, interleaved RGB) back to the projector's input levels:
    /// clipped to \[0,1\], through the inverse of its response per channel.
    fn input_levels(&self, mut drives: Vec<f32>) -> Result<PrjImage> {
        let ImageSize {
            width: pw,
            height: ph,
        } = self.projector_size();
        let gp = self.scene().projector.gamma;
        for px in drives.chunks_exact_mut(3) {
            for c in 0..3 {
                px[c] = px[c].clamp(0.0, 1.0).powf(1.0 / gp[c] as f32);
            }
        }
        PrjImage::from_vec(pw, ph, drives)
    }

    /// Starting drives: invert each camera pixel's local model (direct light only), clip to
    /// \[0,1\], and warp the result to projector space through the true geometry.
    fn per_pixel_start(&self, target: &[f32], mask: &Mask<Camera>) -> Result<Vec<f32>> {
        let inv_cam = invert3(self.cam_mix())?;
        let inv_prj = invert3(self.prj_mix())?;
        let black = self.prj_black();
        let ImageSize {
            width: cw,
            height: ch,
        } = self.camera_size();
        let mut want = vec![0f32; cw * ch * 3];
        for i in 0..cw * ch {
            if !mask.data()[i] {
                continue;
            }
            let (a, gain, konst) = self.pixel_terms(i);
            if gain <= 0.0 {
                continue;
            }
            let s = [0, 1, 2].map(|c| (target[i * 3 + c] - konst[c]) / gain);
            let r = mat3(&inv_cam, s);
            let e = [0, 1, 2].map(|c| {
                if a[c] > 1e-4 {
                    r[c] / a[c] - black[c]
                } else {
                    0.0
                }
            });
            let d = mat3(&inv_prj, e);
            for c in 0..3 {
                want[i * 3 + c] = d[c].clamp(0.0, 1.0);
            }
        }
        let mut out =
            Vec::with_capacity(self.projector_size().width * self.projector_size().height * 3);
        for xy in self.camera_coords() {
            out.extend_from_slice(&sample_cam(&want, ImageSize::new(cw, ch), *xy));
        }
        Ok(out)
    }

    fn check_cam(&self, img: &CamImage, what: &str) -> Result<()> {
        if img.size() != self.camera_size() {
            return Err(Error::Shape(format!(
                "{what} is {}x{}, the virtual camera of scene {:?} is {}",
                img.width(),
                img.height(),
                self.scene().name,
                self.camera_size()
            )));
        }
        Ok(())
    }
}

/// The oracle's problem for one desired image: ½Σ(enc(s) − z)² over the masked camera values,
/// with the sensor signal `s = A·d + c` affine in the projector drives `d` (projector pixels,
/// linear, in \[0,1\]) and `enc` the camera's clip and response curve (camera pixels). For a
/// set of projectors `d` is their drives one after the other and `A·d = Σ_k A_k·d_k`: light
/// adds.
struct Objective<'a> {
    /// The projectors, each alone on the surface.
    sims: Vec<&'a Simulator>,
    /// The desired camera image (encoded values, interleaved RGB).
    z: &'a [f32],
    /// Per camera value: inside the mask.
    inside: Vec<bool>,
    /// The constant part of the sensor signal: A(black) + ambient + glare.
    c: Vec<f32>,
    /// The camera's response exponent γ.
    gamma_c: f32,
}

/// Slope of the encoding is floored near black at this signal (it is infinite at 0).
const S_FLOOR: f32 = 1e-4;

impl Objective<'_> {
    /// Projector k's drives within the drives `d` of all of them.
    fn part<'d>(&self, d: &'d [f32], k: usize) -> &'d [f32] {
        let len = |s: &Simulator| {
            let ImageSize { width, height } = s.projector_size();
            width * height * 3
        };
        let start: usize = self.sims[..k].iter().map(|s| len(s)).sum();
        &d[start..start + len(self.sims[k])]
    }

    /// The sensor signal for drives `d`: A·d + c.
    fn forward(&self, d: &[f32]) -> Vec<f32> {
        let mut s = self.sims[0].sensor(&self.sims[0].drive_to_emission(self.part(d, 0), false));
        for (k, sim) in self.sims.iter().enumerate().skip(1) {
            let more = sim.sensor(&sim.drive_to_emission(self.part(d, k), false));
            s.iter_mut().zip(&more).for_each(|(a, b)| *a += b);
        }
        for (v, k) in s.iter_mut().zip(&self.c) {
            *v += k;
        }
        s
    }

    /// J(d)ᵀ·g: a camera-space signal gradient to a drive gradient, through the Jacobian at
    /// drives `d` (A itself but for the white segment), projector after projector.
    fn adjoint(&self, d: &[f32], g: &[f32]) -> Vec<f32> {
        let mut out = Vec::with_capacity(d.len());
        for (k, sim) in self.sims.iter().enumerate() {
            out.extend(sim.emission_to_drive_adjoint(self.part(d, k), &sim.sensor_adjoint(g)));
        }
        out
    }

    /// The camera's encoded output for signal `s`.
    fn enc(&self, s: f32) -> f32 {
        s.clamp(0.0, 1.0).powf(1.0 / self.gamma_c)
    }

    /// Slope of the encoding, floored near black (it is infinite at 0) and 0 when clipped.
    fn slope(&self, s: f32) -> f32 {
        let gamma_c = self.gamma_c;
        if s >= 1.0 {
            0.0
        } else {
            s.max(S_FLOOR).powf(1.0 / gamma_c - 1.0) / gamma_c
        }
    }

    /// The objective ½Σ(enc(s) − z)² over the masked values of signal `s`.
    fn value(&self, s: &[f32]) -> f64 {
        s.iter()
            .zip(self.z)
            .zip(&self.inside)
            .filter(|(_, m)| **m)
            .map(|((&s, &z), _)| {
                let e = (self.enc(s) - z) as f64;
                e * e
            })
            .sum::<f64>()
            / 2.0
    }

    /// Gauss-Newton weights at the current output `s` of drives `x`; the Jacobi majoriser
    /// diag(JᵀWJ·1) (J has non-negative entries), with `a1` = J·1 = A·1 (every Jacobian of the
    /// white segment's min takes one channel whole). With an LCD's cross-talk J·1 differs from
    /// A·1 by the change of the leaks with level, a few percent of the off-diagonal light: the
    /// step halving of [`Self::descend`] keeps the descent monotone all the same.
    fn majoriser(&self, a1: &[f32], s: &[f32], x: &[f32]) -> Vec<f32> {
        let wa1: Vec<f32> = a1
            .iter()
            .zip(s)
            .zip(&self.inside)
            .map(|((a, &s), &m)| {
                if m {
                    let k = self.slope(s);
                    a * k * k
                } else {
                    0.0
                }
            })
            .collect();
        self.adjoint(x, &wa1)
    }

    /// Gradient of ½Σ(enc(s) − z)² with respect to the drives `x`, whose output is `s`.
    fn gradient(&self, s: &[f32], x: &[f32]) -> Vec<f32> {
        let r: Vec<f32> = s
            .iter()
            .zip(self.z)
            .zip(&self.inside)
            .map(|((&s, &z), &m)| {
                if m {
                    (self.enc(s) - z) * self.slope(s)
                } else {
                    0.0
                }
            })
            .collect();
        self.adjoint(x, &r)
    }

    /// Projected gradient descent from drives `x`, scaled by the majoriser (refreshed every 8
    /// iterations), with step halving whenever the objective would rise; stops early when four
    /// halvings in a row do not help. `a1` = A·1.
    fn descend(&self, mut x: Vec<f32>, a1: &[f32], iterations: usize) -> Vec<f32> {
        let mut s = self.forward(&x);
        let mut f = self.value(&s);
        let mut diag = Vec::new();
        let mut step = 1.0f32;
        for it in 0..iterations {
            if it % 8 == 0 {
                diag = self.majoriser(a1, &s, &x);
            }
            let grad = self.gradient(&s, &x);
            let mut accepted = false;
            for _ in 0..4 {
                let mut next = x.clone();
                for j in 0..next.len() {
                    if diag[j] > 1e-12 {
                        next[j] = (x[j] - step * grad[j] / diag[j]).clamp(0.0, 1.0);
                    }
                }
                let s_next = self.forward(&next);
                let f_next = self.value(&s_next);
                if f_next <= f {
                    x = next;
                    s = s_next;
                    f = f_next;
                    step = (step * 1.25).min(2.0);
                    accepted = true;
                    break;
                }
                step *= 0.5;
            }
            if !accepted {
                break;
            }
        }
        x
    }
}

impl SetSimulator {
    /// The physical ceiling of the set for `desired`: the projector images (one per
    /// projector, in the scene's order) that the true, noise-free model of all of them at once
    /// allows to come closest, as [`Simulator::oracle`] for one: the squared error of the
    /// camera's encoded output against `desired` over the camera pixels in `mask`, inputs in
    /// \[0,1\]. Where the projectors overlap the solver shares the light between them and
    /// uses their sum where one alone cannot reach the desired value.
    ///
    /// Start: each projector's per-pixel inversion of the whole target, weighted at each camera
    /// pixel by its share of the set's light there (its sensor signal at full white over the
    /// set's), so that overlapping projectors start from their share of the light rather than
    /// each from all of it; then the joint descent.
    pub fn oracle(
        &self,
        desired: &CamImage,
        mask: &Mask<Camera>,
        opts: OracleOptions,
    ) -> Result<Vec<PrjImage>> {
        let sims: Vec<&Simulator> = self.projectors().iter().collect();
        for s in &sims {
            s.check_cam(desired, "the desired image")?;
        }
        let (z, gamma_c) = (desired.data(), self.scene().camera.gamma as f32);
        let (inside, target) = masked_target(desired, mask, gamma_c)?;

        // The constant part: every projector's black through the scene, and the room's light
        // once. A·1 of every projector: the majoriser's sum, and each one's share of the light.
        let sizes: Vec<usize> = sims
            .iter()
            .map(|s| s.projector_size().width * s.projector_size().height * 3)
            .collect();
        let mut c = vec![0f32; z.len()];
        let mut a1 = vec![0f32; z.len()];
        let mut each_a1 = Vec::with_capacity(sims.len());
        for (s, &len) in sims.iter().zip(&sizes) {
            let black = s.sensor(&s.drive_to_emission(&vec![0f32; len], true));
            c.iter_mut().zip(&black).for_each(|(a, b)| *a += b);
            let full = s.sensor(&s.drive_to_emission(&vec![1f32; len], false));
            a1.iter_mut().zip(&full).for_each(|(a, b)| *a += b);
            each_a1.push(full);
        }
        sims[0].add_constant(&mut c);
        let mut x = Vec::with_capacity(sizes.iter().sum());
        for (s, own) in sims.iter().zip(&each_a1) {
            let share: Vec<f32> = target
                .iter()
                .zip(own)
                .zip(&a1)
                .map(|((&t, &o), &all)| if all > 1e-9 { t * o / all } else { 0.0 })
                .collect();
            x.extend(s.per_pixel_start(&share, mask)?);
        }
        let problem = Objective {
            sims: sims.clone(),
            z,
            inside,
            c,
            gamma_c,
        };
        let x = problem.descend(x, &a1, opts.iterations);
        sims.iter()
            .enumerate()
            .map(|(k, s)| s.input_levels(problem.part(&x, k).to_vec()))
            .collect()
    }
}

/// Per camera value (interleaved RGB): whether its pixel is in `mask`, and the sensor signal
/// the desired encoded value asks for (clipped to \[0,1\], through the camera's response
/// `gamma_c`).
fn masked_target(
    desired: &CamImage,
    mask: &Mask<Camera>,
    gamma_c: f32,
) -> Result<(Vec<bool>, Vec<f32>)> {
    check_same_size(desired.size(), mask.size(), "oracle mask")?;
    let n = desired.width() * desired.height();
    let inside = (0..n * 3).map(|j| mask.data()[j / 3]).collect();
    let target = desired
        .data()
        .iter()
        .map(|v| v.clamp(0.0, 1.0).powf(gamma_c))
        .collect();
    Ok((inside, target))
}

/// Bilinear sample of an interleaved RGB camera image at pixel coordinate `xy` (centres at
/// integers), zeros outside and for NaN coordinates.
fn sample_cam(
    data: &[f32],
    ImageSize {
        width: w,
        height: h,
    }: ImageSize,
    xy: [f32; 2],
) -> [f32; 3] {
    let [x, y] = xy;
    if !(x > -1.0 && y > -1.0 && x < w as f32 && y < h as f32) {
        return [0.0; 3];
    }
    let (x0, y0) = (x.floor(), y.floor());
    let (fx, fy) = (x - x0, y - y0);
    let (x0, y0) = (x0 as isize, y0 as isize);
    let mut out = [0f32; 3];
    for (dy, wy) in [(0, 1.0 - fy), (1, fy)] {
        for (dx, wx) in [(0, 1.0 - fx), (1, fx)] {
            let (xx, yy) = (x0 + dx, y0 + dy);
            if xx < 0 || yy < 0 || xx >= w as isize || yy >= h as isize {
                continue;
            }
            let i = (yy as usize * w + xx as usize) * 3;
            for c in 0..3 {
                out[c] += wx * wy * data[i + c];
            }
        }
    }
    out
}

fn invert3(m: &[[f32; 3]; 3]) -> Result<[[f32; 3]; 3]> {
    let a = nalgebra::Matrix3::from_fn(|r, c| m[r][c] as f64);
    let inv = a
        .try_inverse()
        .ok_or_else(|| Error::Failed("colour mixing matrix is singular".into()))?;
    Ok([0, 1, 2].map(|r| [0, 1, 2].map(|c| inv[(r, c)] as f32)))
}
