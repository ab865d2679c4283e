//! CompenNet, WarpingNet and CompenNet++ as networks: parameter counts of the layer table,
//! the grid against the CPU warp, gradients through the chain, the simplified playback form.

use candle_core::{DType, Device, Tensor};
use compend::raster::ImageSize;

use crate::common::max_abs;

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
    // Counted by hand from the layers of compend::nn::compennet (docs/architecture.md, "Models";
    // weights k·k·in·out plus out biases per layer):
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
    let w = compend::nn::compennetpp::Variant::Cpu.width();
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
    let wnet =
        compend::nn::WarpingNet::new(vb.pp("warp"), Some(theta), ImageSize::new(w, h), false)
            .unwrap();
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
    let wref =
        compend::nn::WarpingNet::new(vb2.pp("warp"), Some(theta), ImageSize::new(w, h), true)
            .unwrap();
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
        ImageSize::new(w, h),
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
fn simplified_compennet_reproduces_the_full_network() {
    use compend::nn::compennetpp::CompenNetPP;
    let model = CompenNetPP::new(
        compend::nn::compennetpp::GeometryInit::Affine([[0.8, 0.05, 0.0], [0.0, 0.75, 0.02]]),
        ImageSize::new(24, 16),
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
    let diff = super::max_abs_diff(&full, &fast);
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

/// The residual rung's network outputs nothing at first (its last layer starts at zero, with no
/// input skip, no ReLU, no clamp), and once that layer moves its output is signed.
#[test]
fn a_residual_network_starts_at_zero_and_its_correction_is_signed() {
    use candle_core::Var;
    use compend::nn::compennetpp::{CompenNetPP, GeometryInit};
    let grid = Tensor::rand(-0.9f32, 0.9, (1, 8, 12, 2), &Device::Cpu).unwrap();
    let mut model = CompenNetPP::with_width(
        GeometryInit::Fixed(grid),
        ImageSize::new(12, 8),
        false,
        16,
        3,
        &Device::Cpu,
    )
    .unwrap();
    model.make_residual().unwrap();
    let surface = Tensor::rand(0f32, 1.0, (1, 3, 20, 30), &Device::Cpu).unwrap();
    let x = Tensor::rand(0f32, 1.0, (2, 3, 20, 30), &Device::Cpu).unwrap();
    let first = model.forward(&x, &surface).unwrap();
    let at_start = super::max_abs_diff(&first, &first.zeros_like().unwrap());
    assert_eq!(at_start, 0.0);
    let w = model.compen.backbone.conv6.weight().clone();
    Var::from_tensor(&w)
        .unwrap()
        .set(&Tensor::randn(0f32, 0.3, w.dims(), &Device::Cpu).unwrap())
        .unwrap();
    let out = model.forward(&x, &surface).unwrap();
    let min: f32 = out.min_all().unwrap().to_scalar().unwrap();
    let max: f32 = out.max_all().unwrap().to_scalar().unwrap();
    assert!(min < 0.0 && max > 0.0, "correction in [{min}, {max}]");
    // The playback form agrees.
    let fast = model.simplify(&surface).unwrap().forward(&x).unwrap();
    let diff = super::max_abs_diff(&out, &fast);
    assert!(diff < 1e-5, "simplified residual differs by {diff}");
}

/// `nn::stretch` (matrix products, for training) resizes as `resize::resize_bilinear` does,
/// enlarging and shrinking, and gradients flow through it.
#[test]
fn stretch_equals_the_bilinear_resize() {
    use compend::raster::NetImage;
    let img = NetImage::from_fn(7, 5, |x, y| {
        [x as f32 * 0.1, y as f32 * 0.2, ((x * y) % 3) as f32 * 0.3]
    });
    for (w, h) in [(16, 12), (5, 3), (7, 5)] {
        let t = compend::nn::images_to_tensor(std::slice::from_ref(&img)).unwrap();
        let s = compend::nn::stretch(&t, ImageSize::new(w, h)).unwrap();
        let got: NetImage = compend::nn::tensor_to_image(&s, 0).unwrap();
        let want = compend::resize::resize_bilinear(&img, w, h);
        let worst = max_abs(&got, &want);
        assert!(worst < 1e-5, "{w}x{h}: differs by {worst}");
    }
    let v = candle_core::Var::from_tensor(
        &Tensor::ones((1, 3, 4, 4), DType::F32, &Device::Cpu).unwrap(),
    )
    .unwrap();
    let out = compend::nn::stretch(v.as_tensor(), ImageSize::new(8, 8)).unwrap();
    let grads = out.sum_all().unwrap().backward().unwrap();
    // Each source pixel's weights over the enlargement sum to its share: 64 / 16 = 4.
    let g: Vec<f32> = grads
        .get(v.as_tensor())
        .unwrap()
        .flatten_all()
        .unwrap()
        .to_vec1()
        .unwrap();
    assert!(g.iter().all(|x| (x - 4.0).abs() < 1e-4), "{g:?}");
}
