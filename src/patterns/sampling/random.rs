//! Random choices of the sampling images: parameters drawn from the image's ChaCha8 stream and
//! random scalar fields. The order of the draws is part of the generator's output.

use std::f32::consts::PI;

use rand::RngExt;
use rand::rngs::ChaCha8Rng;

use super::field::{CellStyle, Field, NoiseStyle, Wave};

/// Log-uniform value in [lo, hi).
pub(super) fn log_uniform(rng: &mut ChaCha8Rng, lo: f32, hi: f32) -> f32 {
    (rng.random_range(lo.ln()..hi.ln())).exp()
}

fn unit_dir(rng: &mut ChaCha8Rng) -> [f32; 2] {
    let a = rng.random_range(0.0..PI);
    [a.cos(), a.sin()]
}

pub(super) fn point(rng: &mut ChaCha8Rng, reach: f32) -> [f32; 2] {
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

pub(super) fn noise(rng: &mut ChaCha8Rng, freq_lo: f32, freq_hi: f32) -> Field {
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
pub(super) fn random_field(rng: &mut ChaCha8Rng, depth: u32) -> Field {
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
