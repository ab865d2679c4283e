//! Sub-surface scattering (step 3 of [`super`], [`crate::rig::scene::Subsurface`]): a share of
//! the diffusely reflected light spreads under the surface, filtered by its coloured top layer
//! on the way in and out, and its adjoint.
//!
//! Spaces: inputs and outputs are camera images (camera pixels, interleaved linear RGB); the
//! spread is a Gaussian per channel in camera pixels.

use super::kernels::{blur_rgb, gaussian_kernel};

/// The spread of a scene's sub-surface light, prepared for its camera pixels.
#[derive(Clone, Debug)]
pub(super) struct Subsurface {
    share: f32,
    w: usize,
    h: usize,
    /// Per channel: the Gaussian taps (camera pixels), or none for a spread under 0.05 px.
    kernels: [Option<Vec<f32>>; 3],
    /// Per camera pixel and channel: ρ·g (the direct diffuse factor), √ρ·g (light entering
    /// through the top layer) and √ρ (light leaving through it).
    diffuse: Vec<[f32; 3]>,
    entry: Vec<[f32; 3]>,
    exit: Vec<[f32; 3]>,
}

impl Subsurface {
    /// `sigma_px`: the spread per channel in camera pixels; `diffuse` and `albedo`: ρ·g and ρ
    /// per camera pixel of a `w`×`h` camera.
    pub(super) fn new(
        share: f64,
        sigma_px: [f64; 3],
        (w, h): (usize, usize),
        diffuse: &[[f32; 3]],
        albedo: &[[f32; 3]],
    ) -> Self {
        let kernels = sigma_px.map(|s| (s > 0.05).then(|| gaussian_kernel(s)));
        let (entry, exit) = diffuse
            .iter()
            .zip(albedo)
            .map(|(d, a)| {
                let t = a.map(|v| v.max(0.0).sqrt());
                // √ρ·g = ρ·g / √ρ (zero where the albedo is).
                let e = [0, 1, 2].map(|c| if t[c] > 0.0 { d[c] / t[c] } else { 0.0 });
                (e, t)
            })
            .unzip();
        Self {
            share: share as f32,
            w,
            h,
            kernels,
            diffuse: diffuse.to_vec(),
            entry,
            exit,
        }
    }

    /// Diffuse radiance for the gathered projector light `e` (camera space):
    /// (1 − share)·ρ·g·E + share·√ρ·K_c ∗ (√ρ·g·E).
    pub(super) fn forward(&self, e: &[f32]) -> Vec<f32> {
        let spread = self.spread(e, &self.entry, &self.exit);
        self.mix(e, &self.diffuse, spread)
    }

    /// Adjoint of [`Self::forward`]: a diffuse-radiance gradient to a gathered-light gradient,
    /// (1 − share)·ρ·g·q + share·√ρ·g·K_c ∗ (√ρ·q) (the kernels are symmetric).
    pub(super) fn adjoint(&self, q: &[f32]) -> Vec<f32> {
        let spread = self.spread(q, &self.exit, &self.entry);
        self.mix(q, &self.diffuse, spread)
    }

    /// `after`·K_c ∗ (`before`·x), channel by channel.
    fn spread(&self, x: &[f32], before: &[[f32; 3]], after: &[[f32; 3]]) -> Vec<f32> {
        let mut filtered: Vec<f32> = x
            .chunks_exact(3)
            .zip(before)
            .flat_map(|(v, b)| [v[0] * b[0], v[1] * b[1], v[2] * b[2]])
            .collect();
        for (c, k) in self.kernels.iter().enumerate() {
            let Some(k) = k else { continue };
            let blurred = blur_rgb(&filtered, self.w, self.h, k);
            for (f, b) in filtered.chunks_exact_mut(3).zip(blurred.chunks_exact(3)) {
                f[c] = b[c];
            }
        }
        for (f, a) in filtered.chunks_exact_mut(3).zip(after) {
            for c in 0..3 {
                f[c] *= a[c];
            }
        }
        filtered
    }

    /// (1 − share)·`direct`·x + share·`spread`.
    fn mix(&self, x: &[f32], direct: &[[f32; 3]], mut spread: Vec<f32>) -> Vec<f32> {
        let (s, d) = (self.share, 1.0 - self.share);
        for ((o, v), g) in spread
            .chunks_exact_mut(3)
            .zip(x.chunks_exact(3))
            .zip(direct)
        {
            for c in 0..3 {
                o[c] = d * g[c] * v[c] + s * o[c];
            }
        }
        spread
    }
}
