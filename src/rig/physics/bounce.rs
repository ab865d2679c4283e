//! One bounce of projected light between parts of the surface (step 3's `I_i`), on a coarse
//! camera-space grid, and its adjoint.
//!
//! Spaces: inputs and outputs are camera images (camera pixels, interleaved linear RGB); the
//! coarse grid has one cell per `block × block` camera pixels.

use super::kernels::{blur_rgb, gaussian_kernel};

/// Inter-reflection on a coarse camera-space grid: box-average blocks of `block` pixels, blur,
/// bilinear upsampling back.
#[derive(Clone, Debug)]
pub(super) struct Bounce {
    strength: f32,
    pub(super) block: usize,
    cw: usize,
    ch: usize,
    kernel: Vec<f32>,
    /// Per fine column / row: (coarse index 0, coarse index 1, weight of index 1).
    xtaps: Vec<(usize, usize, f32)>,
    ytaps: Vec<(usize, usize, f32)>,
}

impl Bounce {
    pub(super) fn new(w: usize, h: usize, strength: f64, radius: f64) -> Self {
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
    pub(super) fn forward(&self, direct: &[f32]) -> Vec<f32> {
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
    pub(super) fn adjoint(&self, grad: &[f32]) -> Vec<f32> {
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
