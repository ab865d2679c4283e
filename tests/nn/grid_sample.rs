//! The differentiable grid sampler: equal to the CPU reference, gradients equal to finite
//! differences.

use candle_core::{DType, Device, Tensor, Var};
use compend::sample::grid_sample as cpu_grid_sample;
use rand::rngs::ChaCha8Rng;
use rand::{RngExt, SeedableRng};

use super::{case, grid_tensor, to_tensor};
use compend::raster::ImageSize;

#[test]
fn candle_grid_sample_equals_the_cpu_reference() {
    let (img, grid) = case(1, ImageSize::new(13, 9), ImageSize::new(11, 7));
    let expected = cpu_grid_sample(&img, &grid);
    let got = compend::nn::grid_sample(
        &to_tensor(&img, DType::F32),
        &grid_tensor(&grid, DType::F32),
    )
    .unwrap();
    let got: Vec<f32> = got
        .permute((0, 2, 3, 1))
        .unwrap()
        .flatten_all()
        .unwrap()
        .to_vec1()
        .unwrap();
    for (a, b) in got.iter().zip(expected.data()) {
        assert!((a - b).abs() < 1e-5, "{a} vs {b}");
    }
    // Some positions fall outside the image, so the zero padding is exercised.
    assert!(
        grid.data()
            .iter()
            .any(|p| p[0].abs() > 1.0 || p[1].abs() > 1.0)
    );
}

#[test]
fn grid_sample_gradients_match_finite_differences() {
    let (img, grid) = case(2, ImageSize::new(7, 6), ImageSize::new(5, 4));
    let x = Var::from_tensor(&to_tensor(&img, DType::F64)).unwrap();
    let g = Var::from_tensor(&grid_tensor(&grid, DType::F64)).unwrap();
    // A random linear functional of the output, so every output element matters.
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let r: Vec<f64> = (0..3 * 5 * 4)
        .map(|_| rng.random_range(-1.0..1.0))
        .collect();
    let r = Tensor::from_vec(r, (1, 3, 4, 5), &Device::Cpu).unwrap();
    let loss_of = |x: &Tensor, g: &Tensor| -> f64 {
        compend::nn::grid_sample(x, g)
            .unwrap()
            .mul(&r)
            .unwrap()
            .sum_all()
            .unwrap()
            .to_scalar()
            .unwrap()
    };
    let loss = compend::nn::grid_sample(x.as_tensor(), g.as_tensor())
        .unwrap()
        .mul(&r)
        .unwrap()
        .sum_all()
        .unwrap();
    let grads = loss.backward().unwrap();
    let eps = 1e-6;
    for (var, name) in [(&x, "image"), (&g, "grid")] {
        let analytic: Vec<f64> = grads
            .get(var.as_tensor())
            .unwrap()
            .flatten_all()
            .unwrap()
            .to_vec1()
            .unwrap();
        let base: Vec<f64> = var.as_tensor().flatten_all().unwrap().to_vec1().unwrap();
        let shape = var.as_tensor().shape().clone();
        let mut worst = 0f64;
        for i in 0..base.len() {
            let mut plus = base.clone();
            plus[i] += eps;
            let mut minus = base.clone();
            minus[i] -= eps;
            let t = |v: Vec<f64>| Tensor::from_vec(v, shape.clone(), &Device::Cpu).unwrap();
            let numeric = if name == "image" {
                (loss_of(&t(plus), g.as_tensor()) - loss_of(&t(minus), g.as_tensor())) / (2.0 * eps)
            } else {
                (loss_of(x.as_tensor(), &t(plus)) - loss_of(x.as_tensor(), &t(minus))) / (2.0 * eps)
            };
            worst = worst.max((numeric - analytic[i]).abs());
        }
        assert!(
            worst < 1e-6,
            "{name} gradient differs from finite differences by {worst:e}"
        );
        assert!(
            analytic.iter().any(|v| v.abs() > 1e-3),
            "{name} gradient is not trivially zero"
        );
    }
}
