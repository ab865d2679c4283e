//! Scalar fields of the sampling images, in resolution-independent coordinates (see
//! [`super::Canvas`]): waves, rings, spirals, checkers, fractal value noise, blobs, Voronoi cells,
//! products and domain warps, with raw values roughly in \[0,1\].

use std::f32::consts::TAU;

// ---------------------------------------------------------------------------------------------
// Hashing and value noise (integer lattice hashing, no tables)

#[inline]
fn mix64(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// A uniform value in [0,1) for the lattice point (ix, iy) under `key`.
#[inline]
pub(super) fn lattice(key: u64, ix: i32, iy: i32) -> f32 {
    let packed = (ix as u32 as u64) | ((iy as u32 as u64) << 32);
    let h = mix64(key ^ mix64(packed.wrapping_add(0x9E37_79B9_7F4A_7C15)));
    (h >> 40) as f32 / (1u64 << 24) as f32
}

/// Smooth value noise in [0,1] with quintic interpolation between lattice values.
pub(super) fn value_noise(key: u64, p: [f32; 2]) -> f32 {
    let (fx, fy) = (p[0].floor(), p[1].floor());
    let (ix, iy) = (fx as i32, fy as i32);
    let (tx, ty) = (p[0] - fx, p[1] - fy);
    let fade = |t: f32| t * t * t * (t * (t * 6.0 - 15.0) + 10.0);
    let (sx, sy) = (fade(tx), fade(ty));
    let a = lattice(key, ix, iy);
    let b = lattice(key, ix + 1, iy);
    let c = lattice(key, ix, iy + 1);
    let d = lattice(key, ix + 1, iy + 1);
    let top = a + (b - a) * sx;
    let bottom = c + (d - c) * sx;
    top + (bottom - top) * sy
}

#[derive(Clone, Copy, Debug)]
pub(super) enum NoiseStyle {
    Plain,
    /// 1 − |2n − 1| per octave: sharp crests (veins, mountains).
    Ridged,
    /// |2n − 1| per octave: billowy turbulence.
    Turbulent,
}

#[derive(Clone, Copy, Debug)]
pub(super) enum Wave {
    Sine,
    Triangle,
    /// A smoothed square wave; larger `sharp` gives harder edges.
    Square {
        sharp: f32,
    },
    Saw,
}

impl Wave {
    /// Value in [0,1] at phase `t` (in cycles).
    #[inline]
    fn at(self, t: f32) -> f32 {
        match self {
            Wave::Sine => 0.5 + 0.5 * (TAU * t).sin(),
            Wave::Triangle => 1.0 - (2.0 * (t - t.floor()) - 1.0).abs(),
            Wave::Square { sharp } => 0.5 + 0.5 * (sharp * (TAU * t).sin()).tanh(),
            Wave::Saw => t - t.floor(),
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Scalar fields (raw values roughly in [0,1]; `Canvas::render` normalises)

#[derive(Clone, Debug)]
pub(super) enum Field {
    Linear {
        dir: [f32; 2],
        freq: f32,
        phase: f32,
        wave: Wave,
    },
    Radial {
        centre: [f32; 2],
        /// Per-axis scale of the distance (elliptic rings).
        aspect: [f32; 2],
        freq: f32,
        phase: f32,
        wave: Wave,
    },
    Spiral {
        centre: [f32; 2],
        arms: f32,
        twist: f32,
        phase: f32,
        wave: Wave,
    },
    Checker {
        rot: [f32; 2],
        freq: [f32; 2],
        phase: [f32; 2],
        sharp: f32,
    },
    Noise {
        key: u64,
        freq: f32,
        octaves: u32,
        gain: f32,
        offset: [f32; 2],
        style: NoiseStyle,
    },
    Blobs {
        /// (centre, radius, weight)
        blobs: Vec<([f32; 2], f32, f32)>,
    },
    Cells {
        points: Vec<[f32; 2]>,
        values: Vec<f32>,
        style: CellStyle,
    },
    Warped {
        base: Box<Field>,
        wx: Box<Field>,
        wy: Box<Field>,
        amount: f32,
    },
    Product(Box<Field>, Box<Field>),
}

#[derive(Clone, Copy, Debug)]
pub(super) enum CellStyle {
    /// A random flat value per cell (mosaic).
    Flat,
    /// Distance to the nearest point (cellular).
    Distance,
    /// Distance to the second nearest minus the nearest (cell walls).
    Edges,
}

impl Field {
    pub(super) fn eval(&self, p: [f32; 2]) -> f32 {
        match self {
            Field::Linear {
                dir,
                freq,
                phase,
                wave,
            } => wave.at((p[0] * dir[0] + p[1] * dir[1]) * freq + phase),
            Field::Radial {
                centre,
                aspect,
                freq,
                phase,
                wave,
            } => {
                let dx = (p[0] - centre[0]) * aspect[0];
                let dy = (p[1] - centre[1]) * aspect[1];
                wave.at((dx * dx + dy * dy).sqrt() * freq + phase)
            }
            Field::Spiral {
                centre,
                arms,
                twist,
                phase,
                wave,
            } => {
                let dx = p[0] - centre[0];
                let dy = p[1] - centre[1];
                let r = (dx * dx + dy * dy).sqrt();
                let theta = dy.atan2(dx) / TAU; // cycles
                wave.at(theta * arms + r * twist + phase)
            }
            Field::Checker {
                rot,
                freq,
                phase,
                sharp,
            } => {
                let u = p[0] * rot[0] - p[1] * rot[1];
                let v = p[0] * rot[1] + p[1] * rot[0];
                let a = (TAU * (u * freq[0] + phase[0])).sin();
                let b = (TAU * (v * freq[1] + phase[1])).sin();
                0.5 + 0.5 * (sharp * a * b).tanh()
            }
            Field::Noise {
                key,
                freq,
                octaves,
                gain,
                offset,
                style,
            } => fractal_noise(p, *key, *freq, *octaves, *gain, *offset, *style),
            Field::Blobs { blobs } => {
                let mut sum = 0.0;
                for &(c, r, w) in blobs {
                    let dx = p[0] - c[0];
                    let dy = p[1] - c[1];
                    sum += w * (-(dx * dx + dy * dy) / (2.0 * r * r)).exp();
                }
                0.5 + 0.5 * (1.5 * sum).tanh()
            }
            Field::Cells {
                points,
                values,
                style,
            } => cells(p, points, values, *style),
            Field::Warped {
                base,
                wx,
                wy,
                amount,
            } => {
                let q = [
                    p[0] + amount * (wx.eval(p) - 0.5),
                    p[1] + amount * (wy.eval(p) - 0.5),
                ];
                base.eval(q)
            }
            Field::Product(a, b) => a.eval(p) * b.eval(p),
        }
    }
}

/// Fractal value noise at `p`: `octaves` octaves of [`value_noise`] from `key`, the first at
/// frequency `freq` (cycles per unit) shifted by `offset`, each next one with `gain` times the
/// amplitude; `style` shapes each octave. Value in \[0,1\].
fn fractal_noise(
    p: [f32; 2],
    key: u64,
    freq: f32,
    octaves: u32,
    gain: f32,
    offset: [f32; 2],
    style: NoiseStyle,
) -> f32 {
    // Each octave is rotated by ~0.62 rad against the previous one and shifted, so
    // lattice axes do not line up across octaves.
    let (c, s) = (0.8146_f32, 0.5800_f32);
    let mut q = [p[0] * freq + offset[0], p[1] * freq + offset[1]];
    let (mut sum, mut norm, mut amp) = (0.0, 0.0, 1.0);
    for o in 0..octaves {
        let n = value_noise(key.wrapping_add(o as u64), q);
        let n = match style {
            NoiseStyle::Plain => n,
            NoiseStyle::Ridged => 1.0 - (2.0 * n - 1.0).abs(),
            NoiseStyle::Turbulent => (2.0 * n - 1.0).abs(),
        };
        sum += amp * n;
        norm += amp;
        amp *= gain;
        q = [
            2.03 * (c * q[0] - s * q[1]) + 17.13,
            2.03 * (s * q[0] + c * q[1]) + 5.71,
        ];
    }
    sum / norm
}

/// Voronoi cells of `points` at `p`: the value of the nearest point's cell, or a distance, as
/// `style` says. Value in \[0,1\].
fn cells(p: [f32; 2], points: &[[f32; 2]], values: &[f32], style: CellStyle) -> f32 {
    let (mut d1, mut d2, mut best) = (f32::MAX, f32::MAX, 0);
    for (i, c) in points.iter().enumerate() {
        let dx = p[0] - c[0];
        let dy = p[1] - c[1];
        let d = dx * dx + dy * dy;
        if d < d1 {
            d2 = d1;
            d1 = d;
            best = i;
        } else if d < d2 {
            d2 = d;
        }
    }
    let scale = (points.len() as f32).sqrt();
    match style {
        CellStyle::Flat => values[best],
        CellStyle::Distance => (d1.sqrt() * scale).min(1.0),
        CellStyle::Edges => ((d2.sqrt() - d1.sqrt()) * scale * 2.0).min(1.0),
    }
}
