//! Procedural surface albedo, fixed to the surface's (x, y) in world metres and generated from
//! the seed (ChaCha8, value-stable across platforms).

use rand::rngs::ChaCha8Rng;
use rand::{RngExt, SeedableRng};

use super::scene::{Albedo, SURFACE_EXTENT};

/// Smooth value noise on a square lattice covering the surface extent.
#[derive(Clone, Debug)]
pub(crate) struct ValueNoise {
    /// Lattice spacing in metres.
    cell: f64,
    /// Lattice points per side.
    n: usize,
    values: Vec<f32>,
}

impl ValueNoise {
    fn new(rng: &mut ChaCha8Rng, cell: f64) -> Self {
        let n = (2.0 * SURFACE_EXTENT / cell).ceil() as usize + 2;
        let values = (0..n * n).map(|_| rng.random::<f32>()).collect();
        ValueNoise { cell, n, values }
    }

    /// Value in \[0,1\] at (x, y), smoothstep-interpolated between lattice points.
    fn at(&self, x: f64, y: f64) -> f64 {
        let fx = ((x + SURFACE_EXTENT) / self.cell).clamp(0.0, (self.n - 2) as f64);
        let fy = ((y + SURFACE_EXTENT) / self.cell).clamp(0.0, (self.n - 2) as f64);
        let (ix, iy) = (fx.floor() as usize, fy.floor() as usize);
        let (ix, iy) = (ix.min(self.n - 2), iy.min(self.n - 2));
        let s = |t: f64| t * t * (3.0 - 2.0 * t);
        let (tx, ty) = (s(fx - ix as f64), s(fy - iy as f64));
        let v = |i: usize, j: usize| self.values[j * self.n + i] as f64;
        let top = v(ix, iy) * (1.0 - tx) + v(ix + 1, iy) * tx;
        let bottom = v(ix, iy + 1) * (1.0 - tx) + v(ix + 1, iy + 1) * tx;
        top * (1.0 - ty) + bottom * ty
    }
}

/// An albedo function of surface position.
#[derive(Clone, Debug)]
pub(crate) enum AlbedoField {
    Uniform([f64; 3]),
    Texture {
        palette: Vec<[f64; 3]>,
        hue: [ValueNoise; 2],
        shade_noise: [ValueNoise; 2],
        shade: f64,
        sharpness: f64,
    },
}

impl AlbedoField {
    pub fn new(albedo: &Albedo, seed: u64) -> Self {
        match albedo {
            Albedo::Uniform { rgb } => AlbedoField::Uniform(*rgb),
            Albedo::Texture {
                palette,
                scale,
                shade,
                sharpness,
            } => {
                // A stream of its own, so the texture does not depend on anything else drawn
                // from the seed.
                let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x07e4_70a1_bed0_u64);
                let hue = [
                    ValueNoise::new(&mut rng, *scale),
                    ValueNoise::new(&mut rng, *scale / 2.7),
                ];
                let shade_noise = [
                    ValueNoise::new(&mut rng, *scale * 0.6),
                    ValueNoise::new(&mut rng, *scale / 4.3),
                ];
                AlbedoField::Texture {
                    palette: palette.clone(),
                    hue,
                    shade_noise,
                    shade: *shade,
                    sharpness: *sharpness,
                }
            }
        }
    }

    /// Linear reflectance in \[0,1\] per channel at surface position (x, y) metres.
    pub fn at(&self, x: f64, y: f64) -> [f64; 3] {
        match self {
            AlbedoField::Uniform(rgb) => *rgb,
            AlbedoField::Texture {
                palette,
                hue,
                shade_noise,
                shade,
                sharpness,
            } => {
                let h = 0.75 * hue[0].at(x, y) + 0.25 * hue[1].at(x, y);
                // Contrast stretch around ½ (value noise clusters near the middle), then
                // sharpen: larger `sharpness` gives crisper patches of one colour.
                let h = sharpen((h - 0.5) * 2.2 + 0.5, *sharpness);
                let colour = along_palette(palette, h);
                let m = 0.6 * shade_noise[0].at(x, y) + 0.4 * shade_noise[1].at(x, y);
                let m = sharpen((m - 0.5) * 2.0 + 0.5, *sharpness);
                let k = 1.0 - shade * m;
                colour.map(|c| (c * k).clamp(0.0, 1.0))
            }
        }
    }
}

/// Pushes t ∈ \[0,1\] towards 0 or 1 with a logistic of slope `s` (s = 1: nearly unchanged).
fn sharpen(t: f64, s: f64) -> f64 {
    let t = t.clamp(0.0, 1.0);
    if s <= 1.0 {
        return t;
    }
    let f = |u: f64| 1.0 / (1.0 + (-(u - 0.5) * 4.0 * s).exp());
    ((f(t) - f(0.0)) / (f(1.0) - f(0.0))).clamp(0.0, 1.0)
}

/// Piecewise-linear colour along the palette at t ∈ \[0,1\].
fn along_palette(palette: &[[f64; 3]], t: f64) -> [f64; 3] {
    if palette.len() == 1 {
        return palette[0];
    }
    let pos = t.clamp(0.0, 1.0) * (palette.len() - 1) as f64;
    let i = (pos.floor() as usize).min(palette.len() - 2);
    let f = pos - i as f64;
    let (a, b) = (palette[i], palette[i + 1]);
    [0, 1, 2].map(|c| a[c] * (1.0 - f) + b[c] * f)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn texture_is_seeded_and_bounded() {
        let albedo = Albedo::Texture {
            palette: vec![[0.9, 0.1, 0.1], [0.1, 0.9, 0.1], [0.1, 0.1, 0.9]],
            scale: 0.2,
            shade: 0.5,
            sharpness: 2.0,
        };
        let a = AlbedoField::new(&albedo, 1);
        let b = AlbedoField::new(&albedo, 1);
        let c = AlbedoField::new(&albedo, 2);
        let pts: Vec<(f64, f64)> = (0..50)
            .map(|i| (i as f64 * 0.037 - 0.9, (i * 7 % 50) as f64 * 0.03 - 0.7))
            .collect();
        let sa: Vec<[f64; 3]> = pts.iter().map(|&(x, y)| a.at(x, y)).collect();
        let sb: Vec<[f64; 3]> = pts.iter().map(|&(x, y)| b.at(x, y)).collect();
        let sc: Vec<[f64; 3]> = pts.iter().map(|&(x, y)| c.at(x, y)).collect();
        assert_eq!(sa, sb);
        assert_ne!(sa, sc);
        assert!(sa.iter().flatten().all(|v| (0.0..=1.0).contains(v)));
        // It varies: not one flat colour.
        let spread = sa.iter().map(|p| p[0]).fold(f64::MIN, f64::max)
            - sa.iter().map(|p| p[0]).fold(f64::MAX, f64::min);
        assert!(spread > 0.2, "spread {spread}");
    }
}
