//! The CompenNet++ building blocks in candle, one area per module: the differentiable grid
//! sampler (`grid_sample`), the networks and their layer tables (`networks`), training and its
//! sharded step (`training`), the photometric pre-initialisation (`pretrain`), and the CPU ops
//! against candle's own (`ops`: convolutions, ReLU, fused add + ReLU, the SSIM loss and blur).
//! The helpers shared by several modules are here.

mod grid_sample;
mod networks;
mod ops;
mod pretrain;
mod training;

use candle_core::{DType, Device, Tensor};
use compend::raster::{Camera, ImageSize, Network, Rgb};
use compend::sample::Grid;
use rand::rngs::ChaCha8Rng;
use rand::{RngExt, SeedableRng};

/// A random image and a random grid reaching a little outside the image (so zero padding and
/// partially outside corners are exercised), with fractional pixel positions kept away from
/// integers (the sampler's kinks) so finite differences are valid.
fn case(
    seed: u64,
    ImageSize {
        width: w,
        height: h,
    }: ImageSize,
    ImageSize {
        width: gw,
        height: gh,
    }: ImageSize,
) -> (Rgb<Camera>, Grid<Network, Camera>) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let img = Rgb::from_fn(w, h, |_, _| {
        [
            rng.random::<f32>(),
            rng.random::<f32>(),
            rng.random::<f32>(),
        ]
    });
    let coord = |rng: &mut ChaCha8Rng, n: usize| {
        let base = rng.random_range(-1i64..n as i64) as f32;
        let frac = rng.random_range(0.15f32..0.85);
        compend::sample::pixel_to_norm(base + frac, n)
    };
    let grid = Grid::from_fn(gw, gh, |_, _| [coord(&mut rng, w), coord(&mut rng, h)]);
    (img, grid)
}

fn to_tensor(img: &Rgb<Camera>, dtype: DType) -> Tensor {
    compend::nn::images_to_tensor(std::slice::from_ref(img))
        .unwrap()
        .to_dtype(dtype)
        .unwrap()
}

fn grid_tensor(grid: &Grid<Network, Camera>, dtype: DType) -> Tensor {
    let ImageSize {
        width: w,
        height: h,
    } = grid.size();
    let flat: Vec<f32> = grid.data().iter().flatten().copied().collect();
    Tensor::from_vec(flat, (1, h, w, 2), &Device::Cpu)
        .unwrap()
        .to_dtype(dtype)
        .unwrap()
}

fn stack<S: compend::raster::Space>(imgs: &[compend::raster::Rgb<S>]) -> Tensor {
    compend::nn::images_to_tensor(imgs).unwrap()
}

fn max_abs_diff(a: &Tensor, b: &Tensor) -> f64 {
    (a - b)
        .unwrap()
        .abs()
        .unwrap()
        .max_all()
        .unwrap()
        .to_dtype(DType::F64)
        .unwrap()
        .to_scalar()
        .unwrap()
}
