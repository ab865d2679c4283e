//! The CPU ops against candle's own, forward and backward: the matmul convolutions, the
//! parallel ReLU, the fused add + ReLU, the SSIM loss and its blur.

use candle_core::{DType, Device, Tensor, Var};

use super::{case, max_abs_diff, to_tensor};
use compend::raster::{Camera, ImageSize};

/// Random variables of `dims` (normal, σ `std`) in `dtype`.
fn random_var(dims: &[usize], std: f32, dtype: DType) -> Var {
    let t = Tensor::randn(0f32, std, dims, &Device::Cpu).unwrap();
    Var::from_tensor(&t.to_dtype(dtype).unwrap()).unwrap()
}

/// `ours` and `theirs` (two implementations of one layer on the same variables) agree within
/// `tol` forward and within 10·`tol` in the gradient of every variable.
fn assert_same_layer(what: &str, ours: &Tensor, theirs: &Tensor, vars: &[(&str, &Var)], tol: f64) {
    assert_eq!(ours.dims(), theirs.dims(), "{what}: shape");
    let d = max_abs_diff(ours, theirs);
    assert!(d < tol, "{what}: forward differs by {d}");
    // A loss that weights every output differently, so each gradient entry is tested.
    let probe = Tensor::randn(0f32, 1.0, ours.dims(), &Device::Cpu)
        .unwrap()
        .to_dtype(ours.dtype())
        .unwrap();
    let grads = |t: &Tensor| (t * &probe).unwrap().sum_all().unwrap().backward().unwrap();
    let (g1, g2) = (grads(ours), grads(theirs));
    for (name, v) in vars {
        let d = max_abs_diff(g1.get(v).unwrap(), g2.get(v).unwrap());
        assert!(d < 10.0 * tol, "{what}: {name} gradient differs by {d}");
    }
}

/// The matmul convolutions equal candle's own, forward and backward, for every layer shape
/// CompenNet++ uses (3×3 stride 1 and 2, 1×1, 2×2 stride-2 transposed), in f64 and f32.
#[test]
fn matmul_convolutions_equal_candles_with_gradients() {
    use candle_core::Module;
    use candle_nn::{Conv2d, Conv2dConfig, ConvTranspose2d, ConvTranspose2dConfig};
    use compend::nn::conv::{conv_transpose2d, conv2d};
    for (dtype, tol) in [(DType::F64, 1e-10), (DType::F32, 1e-4)] {
        // (cin, cout, k, stride, padding, h, w)
        for &(ci, co, k, s, p, h, w) in &[
            (3, 5, 3, 1, 1, 9, 7),
            (4, 6, 3, 2, 1, 10, 8),
            (3, 4, 3, 2, 1, 9, 7),
            (5, 3, 1, 1, 0, 6, 5),
            (2, 3, 3, 1, 0, 6, 6),
        ] {
            let x = random_var(&[2, ci, h, w], 1.0, dtype);
            let wt = random_var(&[co, ci, k, k], 0.3, dtype);
            let b = random_var(&[co], 0.3, dtype);
            let cfg = Conv2dConfig {
                padding: p,
                stride: s,
                ..Default::default()
            };
            let layer = Conv2d::new(wt.as_tensor().clone(), Some(b.as_tensor().clone()), cfg);
            assert_same_layer(
                &format!("conv {ci}->{co} k{k} s{s} p{p} {dtype:?}"),
                &conv2d(&layer, x.as_tensor()).unwrap(),
                &layer.forward(x.as_tensor()).unwrap(),
                &[("input", &x), ("weight", &wt), ("bias", &b)],
                tol,
            );
            // Without a bias (no row of ones in the columns).
            let layer = Conv2d::new(wt.as_tensor().clone(), None, cfg);
            assert_same_layer(
                &format!("conv {ci}->{co} k{k} s{s} p{p} {dtype:?}, no bias"),
                &conv2d(&layer, x.as_tensor()).unwrap(),
                &layer.forward(x.as_tensor()).unwrap(),
                &[("input", &x), ("weight", &wt)],
                tol,
            );
        }
        for &(ci, co, k, h, w) in &[(4, 3, 2, 5, 3), (6, 2, 2, 4, 4)] {
            let x = random_var(&[2, ci, h, w], 1.0, dtype);
            let wt = random_var(&[ci, co, k, k], 0.3, dtype);
            let b = random_var(&[co], 0.3, dtype);
            let cfg = ConvTranspose2dConfig {
                stride: k,
                ..Default::default()
            };
            let layer =
                ConvTranspose2d::new(wt.as_tensor().clone(), Some(b.as_tensor().clone()), cfg);
            let ours = conv_transpose2d(&layer, x.as_tensor()).unwrap();
            assert_eq!(ours.dims(), &[2, co, h * k, w * k]);
            assert_same_layer(
                &format!("tconv {ci}->{co} k{k} {dtype:?}"),
                &ours,
                &layer.forward(x.as_tensor()).unwrap(),
                &[("input", &x), ("weight", &wt), ("bias", &b)],
                tol,
            );
            let layer = ConvTranspose2d::new(wt.as_tensor().clone(), None, cfg);
            assert_same_layer(
                &format!("tconv {ci}->{co} k{k} {dtype:?}, no bias"),
                &conv_transpose2d(&layer, x.as_tensor()).unwrap(),
                &layer.forward(x.as_tensor()).unwrap(),
                &[("input", &x), ("weight", &wt)],
                tol,
            );
        }
    }
}

/// The parallel ReLU op equals candle's `relu`, forward and backward (gradient passed where the
/// input is ≥ 0, exact zeros included), on tensors larger than one parallel chunk; NaN stays NaN.
#[test]
fn parallel_relu_equals_candles_with_gradients() {
    use compend::nn::conv::relu;
    for dtype in [DType::F64, DType::F32] {
        let x = random_var(&[2, 3, 97, 101], 1.0, dtype);
        // Exact zeros, where the two conventions could differ.
        let zeros = x
            .as_tensor()
            .abs()
            .unwrap()
            .lt(0.05)
            .unwrap()
            .where_cond(&x.as_tensor().zeros_like().unwrap(), x.as_tensor())
            .unwrap();
        x.set(&zeros).unwrap();
        let n_zero = x
            .as_tensor()
            .eq(0.0)
            .unwrap()
            .to_dtype(DType::F32)
            .unwrap()
            .sum_all()
            .unwrap()
            .to_scalar::<f32>()
            .unwrap();
        assert!(n_zero > 100.0, "{n_zero} exact zeros");
        assert_same_layer(
            &format!("relu {dtype:?}"),
            &relu(x.as_tensor()).unwrap(),
            &x.as_tensor().relu().unwrap(),
            &[("input", &x)],
            1e-12,
        );
    }
    let nan = Tensor::new(&[f32::NAN, -1.0, 2.0], &Device::Cpu).unwrap();
    let out = relu(&nan).unwrap().to_vec1::<f32>().unwrap();
    assert!(out[0].is_nan() && out[1] == 0.0 && out[2] == 2.0, "{out:?}");
}

/// The fused add + ReLU equals candle's `relu(a.broadcast_add(b))` bit for bit, forward and
/// both gradients: `b` of `a`'s shape and broadcast over the batch, sizes whose batch rows do
/// not line up with the op's parallel chunks, and exact zero sums, where the gradient passes.
#[test]
fn fused_add_relu_equals_candles_bit_for_bit() {
    use compend::nn::conv::add_relu;
    // Below every difference an f32 or f64 can show: the results must be identical.
    let exact = f64::MIN_POSITIVE;
    for dtype in [DType::F64, DType::F32] {
        for (a_dims, b_dims) in [
            ([4, 3, 37, 41], [1, 3, 37, 41]),
            ([3, 2, 100, 100], [1, 2, 100, 100]),
            ([2, 3, 61, 67], [2, 3, 61, 67]),
            ([1, 5, 9, 7], [1, 5, 9, 7]),
        ] {
            let a = random_var(&a_dims, 1.0, dtype);
            let b = random_var(&b_dims, 1.0, dtype);
            if a_dims == b_dims {
                // Exact zero sums where |b| is small: b = -a there.
                let t = b.as_tensor();
                let zeroing = t.abs().unwrap().lt(0.05).unwrap();
                let neg_a = a.as_tensor().neg().unwrap();
                b.set(&zeroing.where_cond(&neg_a, t).unwrap()).unwrap();
            }
            let ours = add_relu(a.as_tensor(), b.as_tensor()).unwrap();
            let theirs = a
                .as_tensor()
                .broadcast_add(b.as_tensor())
                .unwrap()
                .relu()
                .unwrap();
            assert_same_layer(
                &format!("add-relu {dtype:?} {a_dims:?} + {b_dims:?}"),
                &ours,
                &theirs,
                &[("a", &a), ("b", &b)],
                exact / 10.0,
            );
        }
    }
    let a = Tensor::new(&[f32::NAN, -1.0, 2.0, 0.5], &Device::Cpu).unwrap();
    let b = Tensor::new(&[1.0f32, 0.5, -3.0, -0.5], &Device::Cpu).unwrap();
    let out = add_relu(&a, &b).unwrap().to_vec1::<f32>().unwrap();
    assert!(out[0].is_nan() && out[1..] == [0.0, 0.0, 0.0], "{out:?}");
}

/// The SSIM window's blur op equals replicate padding + candle's convolutions, forward and
/// backward (its adjoint), also on planes narrower than the window.
#[test]
fn gaussian_blur_op_equals_padded_convolutions_with_gradients() {
    use compend::nn::loss::GaussianBlur;
    let dev = Device::Cpu;
    let op = GaussianBlur::ssim_window();
    let r = op.taps.len() / 2;
    let kx = Tensor::from_vec(op.taps.clone(), (1, 1, 1, 2 * r + 1), &dev).unwrap();
    let ky = Tensor::from_vec(op.taps.clone(), (1, 1, 2 * r + 1, 1), &dev).unwrap();
    for (n, c, h, w) in [(2, 3, 9, 13), (1, 2, 4, 3), (1, 1, 16, 16)] {
        let x = random_var(&[n, c, h, w], 1.0, DType::F64);
        let ours = x.as_tensor().apply_op1(op.clone()).unwrap();
        let flat = x.as_tensor().reshape((n * c, 1, h, w)).unwrap();
        let a = flat
            .pad_with_same(3, r, r)
            .unwrap()
            .conv2d(&kx, 0, 1, 1, 1)
            .unwrap();
        let theirs = a
            .pad_with_same(2, r, r)
            .unwrap()
            .conv2d(&ky, 0, 1, 1, 1)
            .unwrap()
            .reshape((n, c, h, w))
            .unwrap();
        assert_same_layer(
            &format!("blur {n}x{c}x{h}x{w}"),
            &ours,
            &theirs,
            &[("input", &x)],
            1e-13,
        );
    }
}

#[test]
fn ssim_loss_equals_the_metric_and_has_gradients() {
    // Two related images: the candle SSIM must equal compend::metrics::ssim (the same definition,
    // computed independently of candle).
    let (a, _) = case(5, ImageSize::new(23, 17), ImageSize::new(1, 1));
    let b = a.map(|v| (0.7 * v + 0.1).min(1.0));
    let b = compend::raster::Rgb::<Camera>::from_fn(23, 17, |x, y| {
        let p = b.get(x, y);
        [p[0], p[1] * if (x + y) % 3 == 0 { 0.5 } else { 1.0 }, p[2]]
    });
    let expected = compend::metrics::ssim(&a, &b).unwrap();
    let ta = to_tensor(&a, DType::F64);
    let tb = to_tensor(&b, DType::F64);
    let got: f64 = compend::nn::loss::ssim(&ta, &tb)
        .unwrap()
        .to_scalar()
        .unwrap();
    assert!(
        (got - expected).abs() < 1e-6,
        "candle SSIM {got} vs metric {expected}"
    );
    // L1 + (1 − SSIM) is zero for identical inputs and its gradient is non-zero otherwise.
    let same: f64 = compend::nn::loss::l1_ssim(&ta, &ta)
        .unwrap()
        .to_scalar()
        .unwrap();
    assert!(same.abs() < 1e-9);
    let v = Var::from_tensor(&tb).unwrap();
    let loss = compend::nn::loss::l1_ssim(v.as_tensor(), &ta).unwrap();
    let g = loss.backward().unwrap();
    let n: f64 = g
        .get(v.as_tensor())
        .unwrap()
        .abs()
        .unwrap()
        .sum_all()
        .unwrap()
        .to_scalar()
        .unwrap();
    assert!(n > 0.0);
}
