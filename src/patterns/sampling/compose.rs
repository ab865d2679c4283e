//! Composition of a sampling image: colour mappings of random fields, optional layering through a
//! soft mask, tone curves, and occasional posterisation, flat patches and grain. Channels are
//! values per pixel of the canvas, in \[0,1\] after the tone curves.

use std::f32::consts::PI;

use rand::RngExt;
use rand::rngs::ChaCha8Rng;

use super::field::{Field, lattice};
use super::random::{log_uniform, noise, point, random_field};
use super::{Canvas, stretch};

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
pub(super) fn hsv_to_rgb(h: f32, s: f32, v: f32) -> [f32; 3] {
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
pub(super) fn compose(rng: &mut ChaCha8Rng, canvas: &Canvas) -> Channels {
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
        25..=44 => channel_mix(rng, canvas, n),
        // A colour ramp through vivid colours, or a natural-looking ramp.
        45..=79 => colour_ramp(rng, canvas, n),
        // HSV: hue, saturation and value from three fields.
        _ => hsv_layer(rng, canvas, n),
    }
}

/// A random mix of three fields (correlated but full-rank colour structure); `n` pixels.
fn channel_mix(rng: &mut ChaCha8Rng, canvas: &Canvas, n: usize) -> Channels {
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

/// A colour ramp through vivid colours, or a natural-looking ramp (related hues from dark to
/// bright, as in stone, wood or clouds), maybe repeated (bands); `n` pixels.
fn colour_ramp(rng: &mut ChaCha8Rng, canvas: &Canvas, n: usize) -> Channels {
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

/// HSV: hue, saturation and value from three fields; `n` pixels.
fn hsv_layer(rng: &mut ChaCha8Rng, canvas: &Canvas, n: usize) -> Channels {
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
