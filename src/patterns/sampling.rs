//! Sampling images: colourful textured projector images `x_i` for training and testing.
//!
//! Each image is generated from its own random stream, derived from `(seed, set, index)` alone, so
//! image `i` of a set can be made without making images `0..i`, and the training and test sets
//! are independent streams (they never share an image). The generator is value-stable: ChaCha8
//! streams, integer hashing and f32 arithmetic in a fixed order, no platform-dependent parts
//! beyond the libm functions (`sin`, `exp`, `powf`, `tanh`).
//!
//! Content: every image is built in resolution-independent coordinates (the same seed at another
//! size gives the same picture resampled, up to aliasing of the finest stripes and per-pixel
//! grain), from scalar
//! fields — linear and radial gradients, sine/triangle/square stripes at several scales and angles,
//! rotated checkers, spirals, fractal value noise (plain, ridged, turbulent), Gaussian blobs,
//! Voronoi cells, products and domain-warped versions of these — turned into colour by one of
//! several mappings (independent channels, a random channel mix, a colour ramp through vivid
//! colours, HSV), optionally layered through a soft mask, then given a random tone curve per
//! channel (robust stretch with some clipping, gamma, S-curve, inversion), and occasionally grain,
//! posterisation and flat patches of extreme colours (black, white, saturated primaries and
//! secondaries). Over a few dozen images every pixel sees dark and bright values in every channel
//! and the per-pixel joint RGB distribution is full-rank (see the coverage test in
//! `tests/patterns.rs`).

use std::f32::consts::{PI, TAU};

use rand::rngs::ChaCha8Rng;
use rand::{RngExt, SeedableRng};

use crate::raster::PrjImage;

/// Which set a sampling image belongs to. The sets use independent random streams.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Set {
    /// `ROOT/train/`: the sampling images `x_i` the models are trained on.
    Train,
    /// `ROOT/test/`: the validation images `y_i`.
    Test,
}

impl Set {
    /// The dataset folder name: `train` or `test`.
    pub fn folder(self) -> &'static str {
        match self {
            Set::Train => "train",
            Set::Test => "test",
        }
    }

    /// The dataset set it is stored in.
    pub fn projector_set(self) -> crate::dataset::ProjectorSet {
        match self {
            Set::Train => crate::dataset::ProjectorSet::Train,
            Set::Test => crate::dataset::ProjectorSet::Test,
        }
    }

    fn tag(self) -> u64 {
        match self {
            Set::Train => 0x7472_6169_6e00_0001, // "train"
            Set::Test => 0x7465_7374_0000_0002,  // "test"
        }
    }
}

/// The random stream of one sampling image: ChaCha8 keyed by a domain constant, the seed, the
/// set and the index (each as 8 little-endian bytes of the 32-byte key).
fn stream(seed: u64, set: Set, index: usize) -> ChaCha8Rng {
    let mut key = [0u8; 32];
    key[0..8].copy_from_slice(b"cmpdSMPL");
    key[8..16].copy_from_slice(&seed.to_le_bytes());
    key[16..24].copy_from_slice(&set.tag().to_le_bytes());
    key[24..32].copy_from_slice(&(index as u64).to_le_bytes());
    ChaCha8Rng::from_seed(key)
}

/// Sampling image `index` (0-based; stored as `img_{index+1:04}.png`) of `set` for `seed`, at
/// `width × height` pixels, RGB in [0,1]. Deterministic: the same arguments always give the same
/// image, and an image depends on no other index.
pub fn sampling_image(seed: u64, set: Set, index: usize, width: usize, height: usize) -> PrjImage {
    let mut rng = stream(seed, set, index);
    let canvas = Canvas::new(width, height);
    let channels = compose(&mut rng, &canvas);
    let mut data = Vec::with_capacity(canvas.len() * 3);
    for i in 0..canvas.len() {
        for ch in &channels {
            data.push(ch[i].clamp(0.0, 1.0));
        }
    }
    PrjImage::from_vec(width, height, data).expect("three channels of width × height values")
}

// ---------------------------------------------------------------------------------------------
// Coordinates

/// Pixel centres in resolution-independent coordinates: the image centre is the origin and the
/// longer side spans one unit, so `u ∈ [-0.5, 0.5]` for a square image.
struct Canvas {
    width: usize,
    height: usize,
    coords: Vec<[f32; 2]>,
}

impl Canvas {
    fn new(width: usize, height: usize) -> Self {
        let s = width.max(height).max(1) as f32;
        let mut coords = Vec::with_capacity(width * height);
        for y in 0..height {
            for x in 0..width {
                coords.push([
                    (x as f32 + 0.5 - width as f32 / 2.0) / s,
                    (y as f32 + 0.5 - height as f32 / 2.0) / s,
                ]);
            }
        }
        Self {
            width,
            height,
            coords,
        }
    }

    fn len(&self) -> usize {
        self.width * self.height
    }

    /// A scalar field sampled at every pixel, stretched to [0,1] between its 0.5 % and 99.5 %
    /// quantiles (clipped outside).
    fn render(&self, f: &Field) -> Vec<f32> {
        let mut v: Vec<f32> = self.coords.iter().map(|&p| f.eval(p)).collect();
        stretch(&mut v, 0.005, 0.995);
        v
    }
}

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
fn lattice(key: u64, ix: i32, iy: i32) -> f32 {
    let packed = (ix as u32 as u64) | ((iy as u32 as u64) << 32);
    let h = mix64(key ^ mix64(packed.wrapping_add(0x9E37_79B9_7F4A_7C15)));
    (h >> 40) as f32 / (1u64 << 24) as f32
}

/// Smooth value noise in [0,1] with quintic interpolation between lattice values.
fn value_noise(key: u64, p: [f32; 2]) -> f32 {
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
enum NoiseStyle {
    Plain,
    /// 1 − |2n − 1| per octave: sharp crests (veins, mountains).
    Ridged,
    /// |2n − 1| per octave: billowy turbulence.
    Turbulent,
}

#[derive(Clone, Copy, Debug)]
enum Wave {
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
enum Field {
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
enum CellStyle {
    /// A random flat value per cell (mosaic).
    Flat,
    /// Distance to the nearest point (cellular).
    Distance,
    /// Distance to the second nearest minus the nearest (cell walls).
    Edges,
}

impl Field {
    fn eval(&self, p: [f32; 2]) -> f32 {
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
            } => {
                // Each octave is rotated by ~0.62 rad against the previous one and shifted, so
                // lattice axes do not line up across octaves.
                let (c, s) = (0.8146_f32, 0.5800_f32);
                let mut q = [p[0] * freq + offset[0], p[1] * freq + offset[1]];
                let (mut sum, mut norm, mut amp) = (0.0, 0.0, 1.0);
                for o in 0..*octaves {
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
            } => {
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

// ---------------------------------------------------------------------------------------------
// Random choices

/// Log-uniform value in [lo, hi).
fn log_uniform(rng: &mut ChaCha8Rng, lo: f32, hi: f32) -> f32 {
    (rng.random_range(lo.ln()..hi.ln())).exp()
}

fn unit_dir(rng: &mut ChaCha8Rng) -> [f32; 2] {
    let a = rng.random_range(0.0..PI);
    [a.cos(), a.sin()]
}

fn point(rng: &mut ChaCha8Rng, reach: f32) -> [f32; 2] {
    [
        rng.random_range(-reach..reach),
        rng.random_range(-reach..reach),
    ]
}

fn wave(rng: &mut ChaCha8Rng) -> Wave {
    match rng.random_range(0..4) {
        0 => Wave::Sine,
        1 => Wave::Triangle,
        2 => Wave::Square {
            sharp: log_uniform(rng, 2.0, 40.0),
        },
        _ => Wave::Saw,
    }
}

fn noise(rng: &mut ChaCha8Rng, freq_lo: f32, freq_hi: f32) -> Field {
    Field::Noise {
        key: rng.random::<u64>(),
        freq: log_uniform(rng, freq_lo, freq_hi),
        octaves: rng.random_range(1..7),
        gain: rng.random_range(0.35..0.7),
        offset: point(rng, 100.0),
        style: match rng.random_range(0..4) {
            0 | 1 => NoiseStyle::Plain,
            2 => NoiseStyle::Ridged,
            _ => NoiseStyle::Turbulent,
        },
    }
}

/// A random scalar field; `depth` limits nesting of products and warps.
fn random_field(rng: &mut ChaCha8Rng, depth: u32) -> Field {
    let roll = rng.random_range(0..100);
    let field = match roll {
        0..=27 => noise(rng, 1.5, 12.0),
        28..=38 => Field::Linear {
            dir: unit_dir(rng),
            freq: log_uniform(rng, 0.4, 28.0),
            phase: rng.random(),
            wave: wave(rng),
        },
        39..=46 => Field::Radial {
            centre: point(rng, 0.6),
            aspect: [rng.random_range(0.5..1.5), rng.random_range(0.5..1.5)],
            freq: log_uniform(rng, 0.5, 20.0),
            phase: rng.random(),
            wave: wave(rng),
        },
        47..=51 => Field::Spiral {
            centre: point(rng, 0.4),
            arms: rng.random_range(1..9) as f32,
            twist: rng.random_range(-12.0..12.0),
            phase: rng.random(),
            wave: wave(rng),
        },
        52..=62 => {
            let a = rng.random_range(0.0..PI);
            let f = log_uniform(rng, 1.0, 16.0);
            Field::Checker {
                rot: [a.cos(), a.sin()],
                freq: [f, f * rng.random_range(0.5..2.0)],
                phase: [rng.random(), rng.random()],
                sharp: log_uniform(rng, 1.0, 40.0),
            }
        }
        63..=75 => {
            let n = rng.random_range(2..14);
            Field::Blobs {
                blobs: (0..n)
                    .map(|_| {
                        (
                            point(rng, 0.6),
                            log_uniform(rng, 0.03, 0.35),
                            rng.random_range(-1.0..1.0),
                        )
                    })
                    .collect(),
            }
        }
        76..=88 => {
            let n = rng.random_range(3..48);
            Field::Cells {
                points: (0..n).map(|_| point(rng, 0.65)).collect(),
                values: (0..n).map(|_| rng.random()).collect(),
                style: match rng.random_range(0..3) {
                    0 => CellStyle::Flat,
                    1 => CellStyle::Distance,
                    _ => CellStyle::Edges,
                },
            }
        }
        _ if depth > 0 => Field::Product(
            Box::new(random_field(rng, depth - 1)),
            Box::new(random_field(rng, depth - 1)),
        ),
        _ => noise(rng, 1.0, 6.0),
    };
    // Domain warping bends straight structures into natural-looking ones (marble, wood, flow).
    if depth > 0 && rng.random_bool(0.3) {
        Field::Warped {
            base: Box::new(field),
            wx: Box::new(noise(rng, 1.0, 5.0)),
            wy: Box::new(noise(rng, 1.0, 5.0)),
            amount: rng.random_range(0.05..0.5),
        }
    } else {
        field
    }
}

/// A colour that is often at the edge of the RGB cube: each component is dark, bright, or
/// anywhere with about equal odds.
fn vivid_colour(rng: &mut ChaCha8Rng) -> [f32; 3] {
    let mut c = [0.0; 3];
    for v in &mut c {
        *v = match rng.random_range(0..3) {
            0 => rng.random_range(0.0..0.12),
            1 => rng.random_range(0.88..1.0),
            _ => rng.random(),
        };
    }
    c
}

/// HSV (all in [0,1], hue in turns) to RGB.
fn hsv_to_rgb(h: f32, s: f32, v: f32) -> [f32; 3] {
    let h6 = (h - h.floor()) * 6.0;
    let k = |n: f32| {
        let k = (n + h6) % 6.0;
        v - v * s * k.min(4.0 - k).clamp(0.0, 1.0)
    };
    [k(5.0), k(3.0), k(1.0)]
}

// ---------------------------------------------------------------------------------------------
// Composition

type Channels = [Vec<f32>; 3];

/// The picture: a colour mapping of random fields, maybe layered, then per-channel tone curves
/// and occasional extras.
fn compose(rng: &mut ChaCha8Rng, canvas: &Canvas) -> Channels {
    let mut img = colour_layer(rng, canvas);
    if rng.random_bool(0.35) {
        let top = colour_layer(rng, canvas);
        let mask = canvas.render(&random_field(rng, 1));
        let level = rng.random_range(0.3..0.7);
        let soft = log_uniform(rng, 0.005, 0.2);
        for i in 0..canvas.len() {
            let a = ((mask[i] - level) / soft).clamp(-1.0, 1.0) * 0.5 + 0.5;
            for c in 0..3 {
                img[c][i] = img[c][i] * (1.0 - a) + top[c][i] * a;
            }
        }
    }
    if rng.random_bool(0.35) {
        // One curve for all channels: keeps the hues of the colour mapping (natural ramps stay
        // natural); the stretch uses the range of all channels together.
        let n = canvas.len();
        let mut joint: Vec<f32> = img.concat();
        tone_curve(rng, &mut joint);
        for (c, ch) in img.iter_mut().enumerate() {
            ch.copy_from_slice(&joint[c * n..(c + 1) * n]);
        }
    } else {
        for ch in &mut img {
            tone_curve(rng, ch);
        }
    }
    if rng.random_bool(0.1) {
        let levels = rng.random_range(2..7) as f32 - 1.0;
        for ch in &mut img {
            for v in ch.iter_mut() {
                *v = (*v * levels).round() / levels;
            }
        }
    }
    if rng.random_bool(0.25) {
        flat_patches(rng, canvas, &mut img);
    }
    if rng.random_bool(0.2) {
        let amp = rng.random_range(0.02..0.1);
        let key = rng.random::<u64>();
        for (c, ch) in img.iter_mut().enumerate() {
            for (i, v) in ch.iter_mut().enumerate() {
                let n = lattice(key ^ c as u64, i as i32, (i >> 31) as i32) - 0.5;
                *v += 2.0 * amp * n;
            }
        }
    }
    img
}

/// Three channels in [0,1] from one of the colour mappings.
fn colour_layer(rng: &mut ChaCha8Rng, canvas: &Canvas) -> Channels {
    let n = canvas.len();
    match rng.random_range(0..100) {
        // Independent fields per channel.
        0..=24 => std::array::from_fn(|_| canvas.render(&random_field(rng, 2))),
        // A random mix of three fields (correlated but full-rank colour structure).
        25..=44 => {
            let f: [Vec<f32>; 3] = std::array::from_fn(|_| canvas.render(&random_field(rng, 2)));
            let m: [[f32; 3]; 3] =
                std::array::from_fn(|_| std::array::from_fn(|_| rng.random_range(-1.0..1.0)));
            let mut out: Channels = std::array::from_fn(|_| vec![0.0; n]);
            for i in 0..n {
                for c in 0..3 {
                    out[c][i] = m[c][0] * f[0][i] + m[c][1] * f[1][i] + m[c][2] * f[2][i];
                }
            }
            for ch in &mut out {
                stretch(ch, 0.0, 1.0);
            }
            out
        }
        // A colour ramp through vivid colours, or a natural-looking ramp (related hues from dark
        // to bright, as in stone, wood or clouds), maybe repeated (bands).
        45..=79 => {
            let natural = rng.random_bool(0.4);
            let t = if natural {
                canvas.render(&Field::Warped {
                    base: Box::new(noise(rng, 1.0, 6.0)),
                    wx: Box::new(noise(rng, 1.0, 4.0)),
                    wy: Box::new(noise(rng, 1.0, 4.0)),
                    amount: rng.random_range(0.0..0.6),
                })
            } else {
                canvas.render(&random_field(rng, 2))
            };
            let k = rng.random_range(2..7);
            let stops: Vec<[f32; 3]> = if natural {
                let hue: f32 = rng.random();
                let spread = rng.random_range(0.02..0.25);
                let mut values: Vec<f32> = (0..k).map(|_| rng.random()).collect();
                values.sort_by(f32::total_cmp);
                values
                    .into_iter()
                    .map(|v| {
                        let h = hue + rng.random_range(-spread..spread);
                        hsv_to_rgb(h, rng.random_range(0.15..0.9), v)
                    })
                    .collect()
            } else {
                (0..k).map(|_| vivid_colour(rng)).collect()
            };
            let repeats = if rng.random_bool(0.3) {
                rng.random_range(2..5) as f32
            } else {
                1.0
            };
            let mut out: Channels = std::array::from_fn(|_| vec![0.0; n]);
            for i in 0..n {
                // Mirrored repetition keeps the ramp continuous.
                let r = t[i] * repeats;
                let r = if (r.floor() as i32) % 2 == 0 {
                    r - r.floor()
                } else {
                    1.0 - (r - r.floor())
                };
                let x = r * (k - 1) as f32;
                let j = (x.floor() as usize).min(k - 2);
                let a = x - j as f32;
                for c in 0..3 {
                    out[c][i] = stops[j][c] * (1.0 - a) + stops[j + 1][c] * a;
                }
            }
            out
        }
        // HSV: hue, saturation and value from three fields.
        _ => {
            let h = canvas.render(&random_field(rng, 2));
            let s = canvas.render(&random_field(rng, 1));
            let v = canvas.render(&random_field(rng, 1));
            let turns = rng.random_range(0.5..3.0);
            let hue0: f32 = rng.random();
            let s0 = rng.random_range(0.0..0.8);
            let v0 = rng.random_range(0.0..0.5);
            let mut out: Channels = std::array::from_fn(|_| vec![0.0; n]);
            for i in 0..n {
                let rgb = hsv_to_rgb(
                    hue0 + turns * h[i],
                    s0 + (1.0 - s0) * s[i],
                    v0 + (1.0 - v0) * v[i],
                );
                for c in 0..3 {
                    out[c][i] = rgb[c];
                }
            }
            out
        }
    }
}

/// A random tone curve on one channel: robust stretch (clipping a few percent at either end,
/// which makes saturated areas), gamma, optional S-curve, optional inversion.
fn tone_curve(rng: &mut ChaCha8Rng, ch: &mut [f32]) {
    let lo = rng.random_range(0.0..0.12);
    let hi = 1.0 - rng.random_range(0.0..0.12);
    stretch(ch, lo, hi);
    let gamma = log_uniform(rng, 0.5, 2.0);
    let s_curve = rng.random_bool(0.35).then(|| rng.random_range(1.0..5.0f32));
    let invert = rng.random_bool(0.5);
    for v in ch.iter_mut() {
        let mut x = v.clamp(0.0, 1.0).powf(gamma);
        if let Some(k) = s_curve {
            x = 0.5 + 0.5 * (k * (x - 0.5)).tanh() / (0.5 * k).tanh();
        }
        *v = if invert { 1.0 - x } else { x };
    }
}

/// One to four soft-edged discs or rotated rectangles of a colour at a corner of the RGB cube.
fn flat_patches(rng: &mut ChaCha8Rng, canvas: &Canvas, img: &mut Channels) {
    let count = rng.random_range(1..5);
    for _ in 0..count {
        let corner = rng.random_range(0..8);
        let colour = [
            (corner & 1) as f32,
            ((corner >> 1) & 1) as f32,
            ((corner >> 2) & 1) as f32,
        ];
        let centre = point(rng, 0.5);
        let size = [rng.random_range(0.05..0.3), rng.random_range(0.05..0.3)];
        let a = rng.random_range(0.0..PI);
        let (ca, sa) = (a.cos(), a.sin());
        let disc = rng.random_bool(0.5);
        let soft = log_uniform(rng, 0.002, 0.05);
        for (i, p) in canvas.coords.iter().enumerate() {
            let dx = p[0] - centre[0];
            let dy = p[1] - centre[1];
            let u = (dx * ca - dy * sa) / size[0];
            let v = (dx * sa + dy * ca) / size[1];
            // Signed distance-like value: negative inside, in units of the patch size.
            let d = if disc {
                (u * u + v * v).sqrt() - 1.0
            } else {
                u.abs().max(v.abs()) - 1.0
            };
            let alpha = (0.5 - d * size[0].min(size[1]) / soft).clamp(0.0, 1.0);
            if alpha > 0.0 {
                for c in 0..3 {
                    img[c][i] = img[c][i] * (1.0 - alpha) + colour[c] * alpha;
                }
            }
        }
    }
}

/// Maps the `q_lo` quantile of `v` to 0 and the `q_hi` quantile to 1, clipping outside. A
/// constant input becomes 0.5.
fn stretch(v: &mut [f32], q_lo: f32, q_hi: f32) {
    if v.is_empty() {
        return;
    }
    let mut sorted = v.to_vec();
    sorted.sort_unstable_by(f32::total_cmp);
    let at = |q: f32| sorted[((sorted.len() - 1) as f32 * q).round() as usize];
    let (lo, hi) = (at(q_lo), at(q_hi));
    if hi - lo > 1e-6 {
        for x in v.iter_mut() {
            *x = ((*x - lo) / (hi - lo)).clamp(0.0, 1.0);
        }
    } else {
        v.fill(0.5);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn deterministic_and_independent_of_other_indices() {
        let a = sampling_image(3, Set::Train, 5, 24, 16);
        let b = sampling_image(3, Set::Train, 5, 24, 16);
        assert_eq!(a, b);
        assert_eq!(a.size(), (24, 16));
        assert_ne!(a, sampling_image(3, Set::Train, 6, 24, 16));
        assert_ne!(a, sampling_image(3, Set::Test, 5, 24, 16));
        assert_ne!(a, sampling_image(4, Set::Train, 5, 24, 16));
        assert!(a.data().iter().all(|v| (0.0..=1.0).contains(v)));
    }

    #[test]
    fn hsv_primaries() {
        let close = |a: [f32; 3], b: [f32; 3]| a.iter().zip(&b).all(|(x, y)| (x - y).abs() < 1e-5);
        assert!(close(hsv_to_rgb(0.0, 1.0, 1.0), [1.0, 0.0, 0.0]));
        assert!(close(hsv_to_rgb(1.0 / 3.0, 1.0, 1.0), [0.0, 1.0, 0.0]));
        assert!(close(hsv_to_rgb(2.0 / 3.0, 1.0, 1.0), [0.0, 0.0, 1.0]));
        assert!(close(hsv_to_rgb(0.5, 0.0, 0.25), [0.25, 0.25, 0.25]));
    }

    #[test]
    fn value_noise_is_continuous_and_bounded() {
        let mut prev = value_noise(7, [0.0, 0.3]);
        for i in 1..2000 {
            let v = value_noise(7, [i as f32 * 0.002, 0.3]);
            assert!((0.0..=1.0).contains(&v));
            assert!((v - prev).abs() < 0.02, "jump at {i}: {prev} → {v}");
            prev = v;
        }
    }
}
