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
    // From Kaiming noise: this test is about learning, not the pre-initialisation.
    settings.photometric = compend::nn::pretrain::PhotometricInit::Kaiming;
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

/// A training step split into shards (run in parallel) gives the loss and every variable's
/// gradient of the unsharded step, up to f32 rounding: for a learned geometry with refinement and
/// for a fixed grid, with even and uneven splits.
#[test]
fn sharded_training_step_equals_the_unsharded_one() {
    use compend::nn::train::{CompenNetPP, GeometryInit};
    let dev = Device::Cpu;
    let (w, h) = (24, 16);
    let fixed = Tensor::rand(-0.9f32, 0.9, (1, h, w, 2), &dev).unwrap();
    for (name, init, refine) in [
        (
            "learned",
            GeometryInit::Affine([[0.8, 0.05, 0.0], [0.0, 0.75, 0.02]]),
            true,
        ),
        ("fixed grid", GeometryInit::Fixed(fixed), false),
    ] {
        let model = CompenNetPP::with_width(init, (w, h), refine, 4, 3, &dev).unwrap();
        for batch in [3, 4] {
            let x = Tensor::rand(0f32, 1.0, (batch, 3, 20, 30), &dev).unwrap();
            let y = Tensor::rand(0f32, 1.0, (batch, 3, h, w), &dev).unwrap();
            let s = Tensor::rand(0f32, 1.0, (1, 3, 20, 30), &dev).unwrap();
            let (v1, g1) = model.gradients(&x, &y, &s, 1e-4, 1).unwrap();
            for shards in [2, batch] {
                let (vk, gk) = model.gradients(&x, &y, &s, 1e-4, shards).unwrap();
                let what = format!("{name}, batch {batch}, {shards} shards");
                assert!(
                    (v1 - vk).abs() < 1e-6 * v1.abs(),
                    "{what}: loss {v1} vs {vk}"
                );
                let mut compared = 0;
                for (var, t) in model.named_tensors() {
                    if !t.is_variable() {
                        continue;
                    }
                    let (a, b) = (g1.get(&t), gk.get(&t));
                    let (Some(a), Some(b)) = (a, b) else {
                        panic!("{what}: {var} has a gradient in only one ({a:?} / {b:?})");
                    };
                    let scale = a
                        .abs()
                        .unwrap()
                        .max_all()
                        .unwrap()
                        .to_scalar::<f32>()
                        .unwrap();
                    let d = max_abs_diff(a, b);
                    assert!(
                        scale > 0.0 && d <= 1e-4 * f64::from(scale),
                        "{what}: {var} gradient differs by {d} (largest entry {scale})"
                    );
                    compared += 1;
                }
                let expected = if refine { 44 } else { 34 };
                assert_eq!(compared, expected, "{what}: variables with gradients");
            }
        }
    }
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

fn tiny_pretrain(seed: u64) -> compend::nn::pretrain::PretrainSettings {
    compend::nn::pretrain::PretrainSettings {
        width: 4,
        patch: 16,
        image: 24,
        pool: 3,
        batch: 2,
        iters: 4,
        lr_step: 3,
        learning_rate: 1e-3,
        weight_decay: 1e-4,
        seed,
    }
}

#[test]
fn pretraining_is_reproducible_round_trips_and_checks_widths() {
    use compend::nn::pretrain::{PhotometricInit, Pretrained, pretrain};
    use std::sync::atomic::AtomicBool;
    let never = AtomicBool::new(false);
    let run = |seed| pretrain(&tiny_pretrain(seed), &Device::Cpu, &never, |_, _, _| {}).unwrap();
    let (a, b, c) = (run(3), run(3), run(4));
    assert_eq!(a.tensors, b.tensors, "the same seed gives the same weights");
    assert_ne!(a.tensors, c.tensors, "another seed gives other weights");
    assert!(a.meta.first_loss.is_finite() && a.meta.final_loss.is_finite());
    // Every CompenNet variable and nothing else, under the CompenNet++ names.
    let names: Vec<&str> = a.tensors.names().collect();
    assert_eq!(
        names.len(),
        2 * (4 + 3 + 10),
        "weight and bias of 17 convolutions"
    );
    assert!(names.iter().all(|n| n.starts_with("compen.")), "{names:?}");

    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("w4.safetensors");
    a.save(&path).unwrap();
    assert!(path.with_extension("json").exists());
    let back = Pretrained::load(&path).unwrap();
    assert_eq!(back.tensors, a.tensors);
    assert_eq!(back.meta.settings, a.meta.settings);
    assert!((back.meta.final_loss - a.meta.final_loss).abs() < 1e-9);
    // Loaded for its own width it resolves; for another width it is refused, naming the file.
    let init = PhotometricInit::File(path.clone());
    assert!(init.resolve(4).unwrap().is_some());
    let err = init.resolve(16).expect_err("width mismatch").to_string();
    assert!(
        err.contains("w4.safetensors") && err.contains("16"),
        "{err}"
    );
    assert_eq!(
        PhotometricInit::Kaiming.resolve(16).unwrap().map(|_| ()),
        None
    );
    // A corrupt weight file and a metadata file of another version are input errors (exit 2).
    std::fs::write(&path, b"not safetensors").unwrap();
    let err = init.resolve(4).expect_err("corrupt");
    assert_eq!(err.exit_code(), 2);
    assert!(err.to_string().contains("w4.safetensors"), "{err}");
    a.save(&path).unwrap();
    let json = path.with_extension("json");
    let text = std::fs::read_to_string(&json).unwrap();
    std::fs::write(
        &json,
        text.replace("\"format_version\": 1", "\"format_version\": 7"),
    )
    .unwrap();
    let err = init.resolve(4).expect_err("old version");
    assert_eq!(err.exit_code(), 2);
    assert!(err.to_string().contains("version 7"), "{err}");
}

/// The shipped weights: they load for both widths, they set every CompenNet variable of a
/// CompenNet++ model, and on synthetic pairs the pre-training never saw (another seed) they
/// undo the surface: at least 10 % below the loss of the input taken as the answer (a network that
/// only copied its input would not be), and far below a Kaiming start.
#[test]
fn shipped_pretrained_weights_undo_the_synthetic_surface() {
    use compend::nn::pretrain::{PREFIX, Pretrained, SURFACE_WEIGHT};
    use compend::patterns::sampling::{Set, sampling_image};
    let side = 128; // the pre-training's image side (its crops are 64²)
    let content: Vec<_> = (0..4)
        .map(|i| sampling_image(9_001, Set::Train, i, side, side))
        .collect();
    let x = stack(&content);
    // A smooth surface, as the pre-training's (made at a quarter of the side and enlarged).
    let s = stack(&[compend::resize::resize(
        &sampling_image(9_002, Set::Test, 0, side / 4, side / 4),
        side,
        side,
        compend::resize::Filter::Bilinear,
    )]);
    let input = x
        .broadcast_sub(&s.affine(SURFACE_WEIGHT, 0.0).unwrap())
        .unwrap()
        .abs()
        .unwrap();
    let score = |t: &Tensor| -> f64 {
        compend::nn::loss::l1_ssim(t, &x)
            .unwrap()
            .to_dtype(DType::F64)
            .unwrap()
            .to_scalar()
            .unwrap()
    };
    let as_is = score(&input);
    for width in [16, 32] {
        let weights = Pretrained::shipped(width).unwrap().expect("shipped");
        assert_eq!(weights.meta.settings.width, width);
        assert!(
            weights.meta.final_loss < 0.7 * weights.meta.first_loss,
            "width {width}: the shipped run's loss fell only {:.3} → {:.3}",
            weights.meta.first_loss,
            weights.meta.final_loss
        );
        let varmap = candle_nn::VarMap::new();
        let vb = candle_nn::VarBuilder::from_varmap(&varmap, DType::F32, &Device::Cpu);
        let net = compend::nn::CompenNet::with_width(vb.pp(PREFIX), width).unwrap();
        compend::nn::layers::seeded_init(&varmap, 1).unwrap();
        let kaiming = score(&net.forward(&input, &s).unwrap());
        assert_eq!(weights.apply(&varmap).unwrap(), 34);
        let pretrained = score(&net.forward(&input, &s).unwrap());
        eprintln!(
            "width {width}: {pretrained:.3} pre-trained, {as_is:.3} as is, {kaiming:.3} Kaiming"
        );
        assert!(
            pretrained < 0.9 * as_is && pretrained < 0.5 * kaiming,
            "width {width}: loss {pretrained:.3} pre-trained, {as_is:.3} for the input as is, {kaiming:.3} from Kaiming"
        );
    }
}

/// Random variables of `dims` (normal, σ `std`) in `dtype`.
fn random_var(dims: &[usize], std: f32, dtype: DType) -> Var {
    let t = Tensor::randn(0f32, std, dims, &Device::Cpu).unwrap();
    Var::from_tensor(&t.to_dtype(dtype).unwrap()).unwrap()
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
