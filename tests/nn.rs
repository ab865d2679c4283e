//! The differentiable grid sampler: equal to the CPU reference, gradients equal to finite
//! differences.

use candle_core::{DType, Device, Tensor, Var};
use compend::raster::{Camera, Network, Rgb};
use compend::sample::{Grid, grid_sample as cpu_grid_sample};
use rand::rngs::ChaCha8Rng;
use rand::{RngExt, SeedableRng};

/// A random image and a random grid reaching a little outside the image (so zero padding and
/// partially outside corners are exercised), with fractional pixel positions kept away from
/// integers (the sampler's kinks) so finite differences are valid.
fn case(
    seed: u64,
    (w, h): (usize, usize),
    (gw, gh): (usize, usize),
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
    let (w, h) = grid.size();
    let flat: Vec<f32> = grid.data().iter().flatten().copied().collect();
    Tensor::from_vec(flat, (1, h, w, 2), &Device::Cpu)
        .unwrap()
        .to_dtype(dtype)
        .unwrap()
}

#[test]
fn candle_grid_sample_equals_the_cpu_reference() {
    let (img, grid) = case(1, (13, 9), (11, 7));
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
    let (img, grid) = case(2, (7, 6), (5, 4));
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

fn count(varmap: &candle_nn::VarMap, prefix: &str) -> usize {
    varmap
        .data()
        .lock()
        .unwrap()
        .iter()
        .filter(|(k, _)| k.starts_with(prefix))
        .map(|(_, v)| v.as_tensor().elem_count())
        .sum()
}

#[test]
fn compennet_matches_the_layer_table() {
    use candle_nn::{VarBuilder, VarMap};
    let varmap = VarMap::new();
    let vb = VarBuilder::from_varmap(&varmap, DType::F32, &Device::Cpu);
    let net = compend::nn::CompenNet::new(vb.pp("compen")).unwrap();
    // Counted by hand from DESIGN.md 5.2 (weights k·k·in·out plus out biases per layer):
    // surface 896 + 18 496 + 73 856 + 295 168 = 388 416; backbone 252 (skip1) + 896 + 2 112 +
    // 18 496 + 8 320 + 73 856 + 295 168 + 295 040 + 32 832 + 8 224 + 867 = 736 063.
    assert_eq!(count(&varmap, "compen.surface."), 388_416);
    assert_eq!(count(&varmap, "compen.backbone."), 736_063);
    assert_eq!(count(&varmap, "compen."), 1_124_479);
    let names: Vec<String> = varmap.data().lock().unwrap().keys().cloned().collect();
    for n in [
        "compen.surface.conv1_s.weight",
        "compen.backbone.skip1.2.bias",
        "compen.backbone.tconv2.weight",
    ] {
        assert!(names.iter().any(|k| k == n), "missing variable {n}");
    }
    // Shapes and range at a tiny size, batch 2 with one shared surface image.
    let x = Tensor::rand(0f32, 1.0, (2, 3, 16, 24), &Device::Cpu).unwrap();
    let s = Tensor::rand(0f32, 1.0, (1, 3, 16, 24), &Device::Cpu).unwrap();
    let y = net.forward(&x, &s).unwrap();
    assert_eq!(y.dims(), &[2, 3, 16, 24]);
    let v: Vec<f32> = y.flatten_all().unwrap().to_vec1().unwrap();
    assert!(v.iter().all(|&p| (0.0..=1.0).contains(&p)));
    assert!(
        v.iter().any(|&p| p > 0.0),
        "a fresh net should not be all black"
    );

    // The CPU rung (`compennet++-cpu`) keeps the design at half the widths: with base width w,
    // the surface branch has 378·w² + 42·w parameters and the backbone 716·w² + 82·w + 255
    // (the same sums as above, by layer); w = 16 gives 97 440 and 184 863.
    let small = VarMap::new();
    let vb = VarBuilder::from_varmap(&small, DType::F32, &Device::Cpu);
    let w = compend::nn::train::Variant::Cpu.width();
    assert_eq!(w, 16);
    let net = compend::nn::CompenNet::with_width(vb.pp("compen"), w).unwrap();
    assert_eq!(count(&small, "compen.surface."), 97_440);
    assert_eq!(count(&small, "compen.backbone."), 184_863);
    let y = net.forward(&x, &s).unwrap();
    assert_eq!(y.dims(), &[2, 3, 16, 24]);
}

#[test]
fn warpingnet_grid_equals_the_cpu_warp_and_gradients_flow() {
    use candle_nn::{VarBuilder, VarMap};
    use compend::warp::{TpsBasis, Warp};
    let (w, h) = (12usize, 8usize);
    let theta = [[0.7f32, 0.05, 0.1], [-0.02, 0.8, -0.05]];
    let varmap = VarMap::new();
    let vb = VarBuilder::from_varmap(&varmap, DType::F32, &Device::Cpu);
    let wnet = compend::nn::WarpingNet::new(vb.pp("warp"), Some(theta), (w, h), false).unwrap();
    assert_eq!(count(&varmap, "warp."), 6 + 76);
    // Same parameters on the CPU side.
    let tps: Vec<Vec<f32>> = wnet.tps.to_vec2().unwrap();
    let warp = Warp {
        theta,
        tps: [tps[0].clone(), tps[1].clone()],
    };
    let cpu = TpsBasis::new(w, h).grid(&warp);
    let gpu: Vec<f32> = wnet
        .grid()
        .unwrap()
        .flatten_all()
        .unwrap()
        .to_vec1()
        .unwrap();
    for (a, b) in gpu.chunks(2).zip(cpu.data()) {
        assert!(
            (a[0] - b[0]).abs() < 1e-5 && (a[1] - b[1]).abs() < 1e-5,
            "{a:?} vs {b:?}"
        );
    }
    // With refinement: 27 586 more parameters, and a near-identity start.
    let varmap2 = VarMap::new();
    let vb2 = VarBuilder::from_varmap(&varmap2, DType::F32, &Device::Cpu);
    let wref = compend::nn::WarpingNet::new(vb2.pp("warp"), Some(theta), (w, h), true).unwrap();
    assert_eq!(count(&varmap2, "warp.refine."), 27_586);
    let r: Vec<f32> = wref
        .grid()
        .unwrap()
        .flatten_all()
        .unwrap()
        .to_vec1()
        .unwrap();
    let t: Vec<f32> = compend::nn::WarpingNet::new(
        VarBuilder::from_varmap(&VarMap::new(), DType::F32, &Device::Cpu),
        Some(theta),
        (w, h),
        false,
    )
    .unwrap()
    .grid()
    .unwrap()
    .flatten_all()
    .unwrap()
    .to_vec1()
    .unwrap();
    assert!(
        r.iter().zip(&t).all(|(a, b)| (a - b).abs() < 5e-3),
        "refinement starts near identity"
    );

    // CompenNet++ chain: warp the capture and surface, compensate, L1 loss; gradients reach θ,
    // the TPS and the backbone.
    let net = compend::nn::CompenNet::new(vb.pp("compen")).unwrap();
    let cap = Tensor::rand(0f32, 1.0, (1, 3, 20, 30), &Device::Cpu).unwrap();
    let surf = Tensor::rand(0f32, 1.0, (1, 3, 20, 30), &Device::Cpu).unwrap();
    let target = Tensor::rand(0f32, 1.0, (1, 3, h, w), &Device::Cpu).unwrap();
    let grid = wnet.grid().unwrap();
    let xw = compend::nn::grid_sample(&cap, &grid).unwrap();
    let sw = compend::nn::grid_sample(&surf, &grid).unwrap();
    let out = net.forward(&xw, &sw).unwrap();
    let loss = (out - target).unwrap().abs().unwrap().mean_all().unwrap();
    let grads = loss.backward().unwrap();
    let data = varmap.data().lock().unwrap();
    for name in [
        "warp.theta",
        "warp.tps",
        "compen.backbone.conv6.weight",
        "compen.surface.conv4_s.weight",
    ] {
        let g = grads
            .get(data[name].as_tensor())
            .unwrap_or_else(|| panic!("no gradient for {name}"));
        let n: f32 = g.abs().unwrap().sum_all().unwrap().to_scalar().unwrap();
        assert!(n > 0.0, "zero gradient for {name}");
    }
}

#[test]
fn ssim_loss_equals_the_metric_and_has_gradients() {
    // Two related images: the candle SSIM must equal compend::metrics::ssim (the same definition,
    // computed independently of candle).
    let (a, _) = case(5, (23, 17), (1, 1));
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

fn stack<S: compend::raster::Space>(imgs: &[compend::raster::Rgb<S>]) -> Tensor {
    compend::nn::images_to_tensor(imgs).unwrap()
}

#[test]
fn compennet_training_learns_reproduces_and_cancels() {
    use compend::nn::train::{Data, Settings, Variant, train};
    use std::sync::atomic::AtomicBool;
    let sys = crate::linear::System::new();
    let mut rng = ChaCha8Rng::seed_from_u64(21);
    let train_imgs: Vec<_> = (0..12).map(|_| crate::linear::texture(&mut rng)).collect();
    let caps: Vec<_> = train_imgs.iter().map(|t| sys.capture(t)).collect();
    let gray = compend::raster::NetImage::filled(32, 32, [77.0 / 255.0; 3]);
    let data = Data {
        captures: stack(&caps),
        surface: stack(&[sys.capture(&gray)]),
        targets: stack(&train_imgs),
    };
    let theta = [[0.8, 0.0, 0.02], [0.0, 0.83, 0.0]];
    let mut settings = Settings::new(Variant::Faster, 4);
    settings.iters = Some(40);
    settings.batch = Some(4);
    assert_eq!(
        settings.resolved(),
        (4, 40, 32),
        "the lr step scales with --iters (400/500·40)"
    );
    let never = AtomicBool::new(false);
    let aff = || compend::nn::train::GeometryInit::Affine(theta);
    let (model, report) = train(&data, aff(), &settings, &never, |_, _, _| {}).unwrap();
    let first: f64 = report.losses[..5].iter().sum::<f64>() / 5.0;
    let last: f64 = report.losses[35..].iter().sum::<f64>() / 5.0;
    assert!(
        last < 0.8 * first,
        "loss should fall: {first:.3} → {last:.3}"
    );
    let out = model
        .forward(&data.captures.narrow(0, 0, 2).unwrap(), &data.surface)
        .unwrap();
    assert_eq!(out.dims(), &[2, 3, 32, 32]);
    // Same seed, same run (a 5-step run: its schedule differs only after its 5th loss).
    let mut short = settings.clone();
    short.iters = Some(5);
    let (_, again) = train(&data, aff(), &short, &never, |_, _, _| {}).unwrap();
    assert_eq!(report.losses[..5], again.losses[..]);
    let mut other = short.clone();
    other.seed = 5;
    let (_, different) = train(&data, aff(), &other, &never, |_, _, _| {}).unwrap();
    assert_ne!(
        again.losses, different.losses,
        "another seed draws other weights and batches"
    );
    // Cancellation before the first step: an error, no model.
    let stop = AtomicBool::new(true);
    let err = train(&data, aff(), &settings, &stop, |_, _, _| {})
        .err()
        .expect("cancelled");
    assert!(err.to_string().contains("cancelled"), "{err}");
}

#[test]
fn simplified_compennet_reproduces_the_full_network() {
    use compend::nn::train::CompenNetPP;
    let model = CompenNetPP::new(
        compend::nn::train::GeometryInit::Affine([[0.8, 0.05, 0.0], [0.0, 0.75, 0.02]]),
        (24, 16),
        true,
        9,
        &Device::Cpu,
    )
    .unwrap();
    let surface = Tensor::rand(0f32, 1.0, (1, 3, 30, 40), &Device::Cpu).unwrap();
    let x = Tensor::rand(0f32, 1.0, (3, 3, 30, 40), &Device::Cpu).unwrap();
    let full = model.forward(&x, &surface).unwrap();
    let simple = model.simplify(&surface).unwrap();
    let fast = simple.forward(&x).unwrap();
    let diff: f32 = (full - fast)
        .unwrap()
        .abs()
        .unwrap()
        .max_all()
        .unwrap()
        .to_scalar()
        .unwrap();
    assert!(
        diff < 1e-4,
        "simplified differs from the full network by {diff}"
    );
    // What remains per frame: the backbone's 736 063 parameters (the surface branch is folded).
    let backbone_params: usize = model
        .named_tensors()
        .iter()
        .filter(|(k, _)| k.starts_with("compen.backbone."))
        .map(|(_, t)| t.elem_count())
        .sum();
    assert_eq!(backbone_params, 736_063);
    assert_eq!(simple.bias.s4.dims(), &[1, 256, 4, 6]);
}
