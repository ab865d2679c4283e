//! The GPU compensation pass against its CPU reference (`compend::playback::reference_frame`),
//! on whatever adapter wgpu finds (lavapipe in CI). Skipped with a printed reason where there is
//! no adapter, unless COMPEND_REQUIRE_GPU_ADAPTER=1.

use compend::fov::DisplayRange;
use compend::gpu::CompensationPass;
use compend::gpu::ConvKernels;
use compend::linear::{Coefficients, Curves, Geometry, LinearModel};
use compend::model::Model;
use compend::model::store::{FORMAT_VERSION, ModelMeta};
use compend::playback::{self, ContentFrame, Placement};
use compend::raster::{Camera, ImageSize, Mask, Network, Rect, Rgb};
use compend::sample::{Grid, pixel_to_norm};
use rand::rngs::ChaCha8Rng;
use rand::{RngExt, SeedableRng};

use crate::common::{gpu, max_abs};

const CAM: ImageSize = ImageSize::new(48, 40);
const NET: ImageSize = ImageSize::new(32, 24);

/// The metadata of a test model of `method` whose output is `network` pixels (camera: [`CAM`]).
fn test_meta(method: compend::model::Method, network: ImageSize) -> ModelMeta {
    ModelMeta {
        format_version: FORMAT_VERSION,
        method,
        network_size: network,
        camera_size: CAM,
        canvas: None,
        training: Default::default(),
        metrics: serde_json::Value::Null,
        timings: Default::default(),
        written_by: "test".into(),
        weights_sha256: None,
        calibration: None,
    }
}

/// A `linear` model with everything the pass must get right: a bent grid that leaves the camera
/// frame in places (zero padding), per-channel curves, per-pixel coefficients that push some
/// values below 0 and above 1 (clamping), and an elliptic FOV mask.
pub fn test_model(seed: u64) -> Model {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let ImageSize {
        width: nw,
        height: nh,
    } = NET;
    let grid: Grid<Network, Camera> = Grid::from_fn(nw, nh, |x, y| {
        let (u, v) = (pixel_to_norm(x as f32, nw), pixel_to_norm(y as f32, nh));
        [
            1.08 * u + 0.1 * v * v - 0.02,
            0.95 * v + 0.12 * u * u + 0.03 * u,
        ]
    });
    let data = (0..nw * nh)
        .map(|_| {
            let mut k = [0f32; 12];
            for (i, v) in k.iter_mut().enumerate() {
                *v = if i < 9 {
                    let diag = if i % 4 == 0 { 1.3 } else { 0.0 };
                    diag + rng.random_range(-0.25..0.25)
                } else {
                    rng.random_range(-0.15..0.1)
                };
            }
            k
        })
        .collect();
    let linear = LinearModel {
        geometry: Geometry::Fixed(grid),
        curves: Curves {
            camera_gamma: [2.0, 2.3, 1.8],
            projector_gamma: [2.2, 1.9, 2.6],
        },
        coeffs: Coefficients {
            width: nw,
            height: nh,
            data,
        },
        camera_size: CAM,
        geometry_size: ImageSize::new(nw, nh),
    };
    let ImageSize {
        width: cw,
        height: ch,
    } = CAM;
    let fov = Mask::from_fn(cw, ch, |x, y| {
        let (u, v) = (pixel_to_norm(x as f32, cw), pixel_to_norm(y as f32, ch));
        u * u / 0.9 + v * v / 0.85 < 1.0
    });
    let meta = test_meta(compend::model::Method::Linear, NET);
    Model::linear(meta, fov, linear)
}

/// How many network pixels the `linear` model puts outside [0, 1]³ in projector linear light
/// for the desired view `desired` (those its gamut map moves).
fn out_of_gamut(model: &Model, desired: &compend::raster::CamImage) -> usize {
    let compend::model::Kind::Linear { simplified, .. } = &model.kind else {
        unreachable!("a linear model")
    };
    let warped = compend::sample::grid_sample(desired, &simplified.grid);
    let c = &simplified.curves;
    warped
        .data()
        .chunks_exact(3)
        .zip(&simplified.coeffs.data)
        .filter(|(px, k)| {
            let a: [f32; 3] = std::array::from_fn(|j| c.camera_linear(j, px[j]));
            (0..3).any(|i| {
                let l = (0..3).map(|j| k[i * 3 + j] * a[j]).sum::<f32>() + k[9 + i];
                !(0.0..=1.0).contains(&l)
            })
        })
        .count()
}

fn random_content(seed: u64, w: usize, h: usize) -> ContentFrame {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let rgba = (0..w * h * 4)
        .map(|_| rng.random_range(0..=255u8))
        .collect();
    ContentFrame::from_rgba(w, h, rgba).unwrap()
}

/// Tolerances: the desired view and the compensation image are f32 on both sides (differences
/// come only from operation order and the GPU's pow); the projector frame is 8-bit on the GPU and
/// must equal the CPU reference rounded to 8 bits within one step on every pixel.
#[test]
fn linear_pass_matches_the_cpu_reference() {
    let Some(ctx) = gpu() else { return };
    let model = test_model(1);
    let placements = [
        // A canvas inside the projector frame, a content frame resized into the area, a range.
        Placement {
            camera_size: CAM,
            area: Rect {
                x: 5,
                y: 6,
                width: 36,
                height: 27,
            },
            range: DisplayRange {
                low: 0.1,
                high: 0.85,
            },
            network_size: NET,
            projector_size: ImageSize::new(80, 60),
            canvas: Rect {
                x: 10,
                y: 12,
                width: 61,
                height: 41,
            },
        },
        // The model's own placement on a full-frame canvas at full range.
        Placement::for_model(&model, ImageSize::new(72, 50), DisplayRange::FULL).unwrap(),
    ];
    for (k, p) in placements.iter().enumerate() {
        let mut pass = CompensationPass::new(ctx, &model, *p).unwrap();
        // Two frames of different sizes through the same pass (the content texture is rebuilt).
        for (f, (w, h)) in [(37usize, 29usize), (p.area.width, p.area.height)]
            .into_iter()
            .enumerate()
        {
            let content = random_content(10 * k as u64 + f as u64, w, h);
            pass.run(ctx, &content).unwrap();
            let desired_cpu = playback::desired_view(&content, p)
                .unwrap()
                .masked(&model.fov)
                .unwrap();
            let desired_gpu = pass.read_desired(ctx).unwrap();
            let net_cpu = playback::reference_network(&model, &content, p).unwrap();
            let net_gpu = pass.read_network(ctx).unwrap();
            let frame_cpu = playback::reference_frame(&model, &content, p).unwrap();
            let frame_gpu = pass.read_output(ctx).unwrap();
            let (e_desired, e_net) = (
                max_abs(&desired_cpu, &desired_gpu),
                max_abs(&net_cpu, &net_gpu),
            );
            let steps: Vec<i32> = frame_cpu
                .data()
                .iter()
                .zip(frame_gpu.data())
                .map(|(c, g)| compend::pngio::to_u8(*c) as i32 - (g * 255.0).round() as i32)
                .collect();
            let worst = steps.iter().map(|d| d.abs()).max().unwrap();
            let off = steps.iter().filter(|d| **d != 0).count();
            eprintln!(
                "placement {k} content {w}x{h}: desired max |Δ| {e_desired:.2e}, network max |Δ| \
                 {e_net:.2e}, frame: {off} of {} values one step off, worst {worst} step(s)",
                steps.len()
            );
            assert!(e_desired <= 1e-5, "desired view differs by {e_desired}");
            assert!(e_net <= 2e-4, "compensation image differs by {e_net}");
            // The gamut map is compared too: enough pixels take it.
            let mapped = out_of_gamut(&model, &desired_cpu);
            assert!(
                mapped * 20 > NET.width * NET.height,
                "{mapped} pixels through the gamut map"
            );
            assert!(worst <= 1, "projector frame differs by {worst} 8-bit steps");
            assert_eq!(frame_gpu.size(), p.projector_size);
        }
    }
}

/// The pass is built once; each frame is only an upload and a dispatch, and frames do not leak
/// into each other.
#[test]
fn pass_is_reused_across_frames() {
    let Some(ctx) = gpu() else { return };
    let model = test_model(2);
    let p = Placement::for_model(&model, ImageSize::new(64, 48), DisplayRange::FULL).unwrap();
    let mut pass = CompensationPass::new(ctx, &model, p).unwrap();
    let a = random_content(5, 20, 15);
    let b = random_content(6, 20, 15);
    pass.run(ctx, &a).unwrap();
    let first = pass.read_output(ctx).unwrap();
    pass.run(ctx, &b).unwrap();
    pass.run(ctx, &a).unwrap();
    assert_eq!(pass.read_output(ctx).unwrap(), first);
}

/// `compend bench-gpu` at tiny sizes: one row per projector size with the copy, the pass, their
/// ratio and the virtual-rig counts, in JSON and markdown, with the convolution kernels asked
/// for.
#[test]
#[cfg(feature = "benches")]
fn bench_gpu_writes_ratios() {
    if gpu().is_none() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("bg");
    let o = crate::common::compend(&[
        "bench-gpu",
        "--out",
        out.to_str().unwrap(),
        "--sizes",
        "64x48,100x75",
        "--iters",
        "3",
        "--seconds",
        "0.25",
        "--camera",
        "80x60",
        "--network",
        "32x32",
        "--content",
        "64x36",
        "--compennet-iters",
        "2",
        "--conv-kernels",
        "tiled",
    ]);
    crate::common::assert_code(&o, 0);
    let v: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("bench-gpu.json")).unwrap()).unwrap();
    let rows = v["rows"].as_array().unwrap();
    assert_eq!(rows.len(), 2);
    // The report says whether the adapter is software, and the markdown warns about it then.
    let software = v["software_adapter"].as_bool().unwrap();
    let md = std::fs::read_to_string(out.join("bench-gpu.md")).unwrap();
    assert_eq!(md.contains("renders in software"), software);
    // The convolution kernels asked for (`--conv-kernels tiled`), in both reports.
    assert_eq!(v["conv_kernels"], "tiled");
    assert!(md.contains("tiled convolutions"), "{md}");
    for r in rows {
        // By default the `linear` model has the lattice training gives: the projector's
        // resolution (rounded up to multiples of 4) at these sizes.
        let (pw, ph) = (
            r["projector"][0].as_u64().unwrap(),
            r["projector"][1].as_u64().unwrap(),
        );
        assert_eq!(
            (
                r["lattice"][0].as_u64().unwrap(),
                r["lattice"][1].as_u64().unwrap()
            ),
            (pw.div_ceil(4) * 4, ph.div_ceil(4) * 4),
            "{r}"
        );
        assert!(r["copy"]["wall_ms"].as_f64().unwrap() > 0.0, "{r}");
        let stages = r["linear_stages"].as_array().unwrap();
        let names: Vec<_> = stages
            .iter()
            .map(|s| s["stage"].as_str().unwrap())
            .collect();
        assert_eq!(names, ["place", "photometric", "canvas"], "{r}");
        assert!(
            stages.iter().all(|s| s["wall_ms"].as_f64().unwrap() > 0.0),
            "{r}"
        );
        assert!(r["linear_over_copy"].as_f64().unwrap() > 0.0, "{r}");
        assert!(r["compennet"]["wall_ms"].as_f64().unwrap() > 0.0, "{r}");
        assert!(r["compennet_over_copy"].as_f64().unwrap() > 0.0, "{r}");
        let rig = &r["virtual_rig"];
        assert!(rig["refreshes"].as_u64().unwrap() == 15, "{r}");
        assert!(rig["shown"].as_u64().unwrap() >= 1, "{r}");
        let alone = &r["headless"];
        assert!(alone["refreshes"].as_u64().unwrap() == 15, "{r}");
        assert!(alone["shown"].as_u64().unwrap() >= 1, "{r}");
        assert!(alone["pipeline_ms_mean"].as_f64().unwrap() > 0.0, "{r}");
    }
    let md = std::fs::read_to_string(out.join("bench-gpu.md")).unwrap();
    assert!(
        md.contains("| 64x48 |") && md.contains("| 100x75 |"),
        "{md}"
    );
}

/// `compend bench-gpu --model`: a trained `linear` model is timed on its own lattice; a
/// CompenNet++ model or a folder that holds no model is refused with exit 2, naming it.
#[test]
#[cfg(feature = "benches")]
fn bench_gpu_times_a_trained_linear_or_residual_model() {
    if gpu().is_none() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let linear = dir.path().join("linear");
    test_model(3).save(&linear).unwrap();
    let cnet = dir.path().join("cnet");
    compennet_test_model(3).save(&cnet).unwrap();
    let run = |model: &std::path::Path, out: &str| {
        let out = dir.path().join(out);
        let o = crate::common::compend(&[
            "bench-gpu",
            "--out",
            out.to_str().unwrap(),
            "--model",
            model.to_str().unwrap(),
            "--sizes",
            "64x48",
            "--iters",
            "2",
            "--seconds",
            "0",
            "--compennet-iters",
            "0",
            "--content",
            "64x36",
        ]);
        (o, out)
    };
    let (o, out) = run(&linear, "bl");
    crate::common::assert_code(&o, 0);
    let v: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("bench-gpu.json")).unwrap()).unwrap();
    assert_eq!(
        v["rows"][0]["lattice"],
        serde_json::json!([NET.width, NET.height]),
        "{v}"
    );
    assert_eq!(
        v["camera"],
        serde_json::json!([CAM.width, CAM.height]),
        "{v}"
    );
    // A residual rung's model is timed in the `linear` columns, on its `linear` part's lattice.
    let residual = dir.path().join("residual");
    residual_test_model(3, compend::model::Method::CompenNetPpResFull)
        .save(&residual)
        .unwrap();
    let (o, out) = run(&residual, "br");
    crate::common::assert_code(&o, 0);
    let v: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("bench-gpu.json")).unwrap()).unwrap();
    assert_eq!(v["model_method"], "compennet++-res-full", "{v}");
    assert_eq!(
        v["rows"][0]["lattice"],
        serde_json::json!([NET.width, NET.height]),
        "{v}"
    );
    assert!(
        v["rows"][0]["linear"]["wall_ms"].as_f64().unwrap() > 0.0,
        "{v}"
    );
    let md = std::fs::read_to_string(out.join("bench-gpu.md")).unwrap();
    assert!(
        md.contains("the trained compennet++-res-full model"),
        "{md}"
    );
    for (model, says) in [(&cnet, "compennet"), (&dir.path().to_path_buf(), "")] {
        let (o, out) = run(model, "refused");
        crate::common::assert_code(&o, 2);
        let err = crate::common::stderr(&o);
        assert!(
            err.contains(model.to_str().unwrap()) && err.contains(says),
            "{err}"
        );
        assert!(!out.exists());
    }
}

/// Network size of the CompenNet++ tests: the backbone's layer widths 36, 18, 9 are not all
/// multiples of the kernels' 4 pixels per invocation.
const CNET: ImageSize = ImageSize::new(36, 28);

/// A CompenNet++ model (fixed bent grid, as `compennet-sl` stores it) on the same camera and
/// network sizes, with seeded weights, non-zero biases everywhere (the GPU must add them) and
/// the output layer shifted so that most outputs land strictly inside (0, 1): the comparison then
/// sees the network's arithmetic, not just clamps.
pub fn compennet_test_model(seed: u64) -> Model {
    compennet_test_model_of_width(seed, compend::nn::compennet::PAPER_WIDTH)
}

/// [`compennet_test_model`] with CompenNet's base channel width `width` (channels).
fn compennet_test_model_of_width(seed: u64, width: usize) -> Model {
    use candle_core::{Device, Tensor, Var};
    use compend::nn::compennetpp::{CompenNetPP, GeometryInit};

    let ImageSize {
        width: nw,
        height: nh,
    } = CNET;
    let grid: Vec<f32> = (0..nh)
        .flat_map(|y| (0..nw).map(move |x| (x, y)))
        .flat_map(|(x, y)| {
            let (u, v) = (pixel_to_norm(x as f32, nw), pixel_to_norm(y as f32, nh));
            [
                1.08 * u + 0.1 * v * v - 0.02,
                0.95 * v + 0.12 * u * u + 0.03 * u,
            ]
        })
        .collect();
    let grid = Tensor::from_vec(grid, (1, nh, nw, 2), &Device::Cpu).unwrap();
    let net = CompenNetPP::with_width(
        GeometryInit::Fixed(grid),
        CNET,
        false,
        width,
        seed,
        &Device::Cpu,
    )
    .unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(seed + 100);
    for (name, t) in net.named_tensors() {
        if !t.is_variable() || !name.ends_with(".bias") {
            continue;
        }
        let n = t.elem_count();
        let shift = if name == "compen.backbone.conv6.bias" {
            0.35
        } else {
            0.0
        };
        let b: Vec<f32> = (0..n)
            .map(|_| shift + rng.random_range(-0.05..0.05))
            .collect();
        Var::from_tensor(&t)
            .unwrap()
            .set(&Tensor::from_vec(b, n, &Device::Cpu).unwrap())
            .unwrap();
    }
    let ImageSize {
        width: cw,
        height: ch,
    } = CAM;
    let fov = Mask::from_fn(cw, ch, |x, y| {
        let (u, v) = (pixel_to_norm(x as f32, cw), pixel_to_norm(y as f32, ch));
        u * u / 0.9 + v * v / 0.85 < 1.0
    });
    let surface: Rgb<Camera> = Rgb::from_vec(
        cw,
        ch,
        (0..cw * ch * 3)
            .map(|_| rng.random_range(0.1..0.6))
            .collect(),
    )
    .unwrap()
    .masked(&fov)
    .unwrap();
    let meta = test_meta(compend::model::Method::CompenNetSl, CNET);
    Model::compennet(meta, fov, net, surface).unwrap()
}

/// Tolerances for the CompenNet++ family: the desired view is the same stage as for `linear`
/// (≤ 1e-5); the compensation image is f32 on both sides through 15 layers (differences from
/// summation order only): ≤ 1e-4; the projector frame within one 8-bit step of the CPU reference
/// rounded to 8 bits on every value (a step only where the f32 values straddle a rounding tie).
/// Both convolution kernels of the wide layers (direct and tiled) are held to them.
#[test]
fn compennet_pass_matches_the_cpu_reference() {
    let Some(ctx) = gpu() else { return };
    for kernels in [
        ConvKernels::Direct,
        ConvKernels::Tiled,
        ConvKernels::Measured,
    ] {
        compennet_pass_matches(&ctx.with_conv_kernels(kernels));
    }
}

/// [`compennet_pass_matches_the_cpu_reference`] with `ctx`'s convolution kernels.
fn compennet_pass_matches(ctx: &compend::gpu::GpuContext) {
    let model = compennet_test_model(3);
    let placements = [
        Placement {
            camera_size: CAM,
            area: Rect {
                x: 5,
                y: 6,
                width: 36,
                height: 27,
            },
            range: DisplayRange {
                low: 0.1,
                high: 0.85,
            },
            network_size: CNET,
            projector_size: ImageSize::new(80, 60),
            canvas: Rect {
                x: 10,
                y: 12,
                width: 61,
                height: 41,
            },
        },
        Placement::for_model(&model, ImageSize::new(72, 50), DisplayRange::FULL).unwrap(),
    ];
    for (k, p) in placements.iter().enumerate() {
        let mut pass = CompensationPass::new(ctx, &model, *p).unwrap();
        for (f, (w, h)) in [(37usize, 29usize), (p.area.width, p.area.height)]
            .into_iter()
            .enumerate()
        {
            let content = random_content(20 + 10 * k as u64 + f as u64, w, h);
            pass.run(ctx, &content).unwrap();
            let desired_cpu = playback::desired_view(&content, p)
                .unwrap()
                .masked(&model.fov)
                .unwrap();
            let e_desired = max_abs(&desired_cpu, &pass.read_desired(ctx).unwrap());
            let net_cpu = playback::reference_network(&model, &content, p).unwrap();
            let net_gpu = pass.read_network(ctx).unwrap();
            let e_net = max_abs(&net_cpu, &net_gpu);
            let inside = net_cpu
                .data()
                .iter()
                .filter(|v| **v > 0.0 && **v < 1.0)
                .count() as f64
                / net_cpu.data().len() as f64;
            let frame_cpu = playback::reference_frame(&model, &content, p).unwrap();
            let frame_gpu = pass.read_output(ctx).unwrap();
            let steps: Vec<i32> = frame_cpu
                .data()
                .iter()
                .zip(frame_gpu.data())
                .map(|(c, g)| compend::pngio::to_u8(*c) as i32 - (g * 255.0).round() as i32)
                .collect();
            let worst = steps.iter().map(|d| d.abs()).max().unwrap();
            let off = steps.iter().filter(|d| **d != 0).count();
            eprintln!(
                "compennet ({:?}) placement {k} content {w}x{h}: desired max |Δ| {e_desired:.2e}, \
                 network max |Δ| {e_net:.2e} ({:.0}% of values inside (0,1)), frame: {off} of {} \
                 values off, worst {worst} step(s)",
                ctx.conv,
                100.0 * inside,
                steps.len()
            );
            assert!(inside > 0.4, "only {inside} of the outputs inside (0,1)");
            assert!(e_desired <= 1e-5, "desired view differs by {e_desired}");
            assert!(e_net <= 1e-4, "compensation image differs by {e_net}");
            assert!(worst <= 1, "projector frame differs by {worst} 8-bit steps");
            assert_eq!(frame_gpu.size(), p.projector_size);
        }
    }
}

/// A residual rung's model (`method`: its CompenNet's widths, the paper's for
/// `compennet++-res-full`, half of them for `compennet++-res`): [`test_model`]'s `linear` part
/// (its 32×24 lattice) plus a CompenNet as [`compennet_test_model`]'s (36×28: the correction is
/// resampled, not just enlarged) with the residual tail and a last layer of random weights, so
/// the correction is far from zero and signed.
fn residual_test_model(seed: u64, method: compend::model::Method) -> Model {
    use candle_core::{Device, Tensor, Var};
    use compend::model::Kind;
    let Kind::Linear { model: linear, .. } = test_model(seed).kind else {
        unreachable!("test_model is linear")
    };
    let width = compend::nn::compennetpp::Variant::from_method(method.name())
        .expect("a CompenNet++ rung")
        .width();
    let cnn = compennet_test_model_of_width(seed, width);
    let fov = cnn.fov.clone();
    let Kind::CompenNet {
        mut net, surface, ..
    } = cnn.kind
    else {
        unreachable!("compennet_test_model is a CompenNet")
    };
    net.make_residual().unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(seed + 7);
    let w = net.compen.backbone.conv6.weight().clone();
    let n = w.elem_count();
    let values: Vec<f32> = (0..n).map(|_| rng.random_range(-0.2..0.2)).collect();
    Var::from_tensor(&w)
        .unwrap()
        .set(&Tensor::from_vec(values, w.dims(), &Device::Cpu).unwrap())
        .unwrap();
    let meta = test_meta(method, NET);
    Model::residual(meta, fov, *linear, *net, surface).unwrap()
}

/// The residual rungs' pass (linear, the correction network, their sum) against the CPU
/// reference ([`compend::model::add_correction`] of the two parts), with the CompenNet
/// tolerances: the compensation image within 1e-4, the frame within one 8-bit step; for both
/// rungs' widths and both convolution kernels.
#[test]
fn residual_pass_matches_the_cpu_reference() {
    use compend::model::Method;
    let Some(ctx) = gpu() else { return };
    for kernels in [
        ConvKernels::Direct,
        ConvKernels::Tiled,
        ConvKernels::Measured,
    ] {
        let ctx = ctx.with_conv_kernels(kernels);
        for method in [Method::CompenNetPpResFull, Method::CompenNetPpRes] {
            residual_pass_matches(&ctx, residual_test_model(5, method));
        }
    }
}

/// [`residual_pass_matches_the_cpu_reference`] for one model.
fn residual_pass_matches(ctx: &compend::gpu::GpuContext, model: Model) {
    let p = Placement::for_model(&model, ImageSize::new(72, 50), DisplayRange::FULL).unwrap();
    assert_eq!(p.network_size, NET);
    let mut pass = CompensationPass::new(ctx, &model, p).unwrap();
    let content = random_content(41, 37, 29);
    pass.run(ctx, &content).unwrap();
    let net_cpu = playback::reference_network(&model, &content, &p).unwrap();
    let net_gpu = pass.read_network(ctx).unwrap();
    let e_net = max_abs(&net_cpu, &net_gpu);
    // The correction matters: the result is not the linear part's.
    let desired = playback::desired_view(&content, &p).unwrap();
    let compend::model::Kind::Residual { base, .. } = &model.kind else {
        unreachable!()
    };
    let linear_only = base.apply(&desired.masked(&model.fov).unwrap());
    let moved = max_abs(&net_cpu, &linear_only);
    let frame_cpu = playback::reference_frame(&model, &content, &p).unwrap();
    let frame_gpu = pass.read_output(ctx).unwrap();
    let worst = frame_cpu
        .data()
        .iter()
        .zip(frame_gpu.data())
        .map(|(c, g)| (compend::pngio::to_u8(*c) as i32 - (g * 255.0).round() as i32).abs())
        .max()
        .unwrap();
    eprintln!(
        "{} ({:?}): network max |Δ| {e_net:.2e} (correction moves it by up to {moved:.2}), \
         frame worst {worst} step(s)",
        model.meta.method, ctx.conv
    );
    let m = model.meta.method;
    assert!(
        moved > 0.05,
        "{m}: the correction changed nothing ({moved})"
    );
    assert!(e_net <= 1e-4, "{m}: compensation image differs by {e_net}");
    assert!(
        worst <= 1,
        "{m}: projector frame differs by {worst} 8-bit steps"
    );
}

/// Each layer's activation on the GPU against candle's, layer by layer, on one frame (a failure
/// names the first layer that differs), with each choice of kernel for the wide layers; the
/// layers with 16 or more output channels must run the kernel asked for, or when it is
/// measured, both must have been timed and the faster kept.
#[test]
fn compennet_layers_match_candle() {
    let Some(ctx) = gpu() else { return };
    for (kernels, wide) in [
        (ConvKernels::Direct, Some(["conv", "tconv"])),
        (ConvKernels::Tiled, Some(["conv_tiled", "tconv_tiled"])),
        (ConvKernels::Measured, None),
    ] {
        compennet_layers_match(&ctx.with_conv_kernels(kernels), wide);
    }
}

/// [`compennet_layers_match_candle`] with `ctx`'s kernels; `wide` is the entry point the wide
/// convolutions and the transposed ones must use (`None`: the faster of the two as timed).
fn compennet_layers_match(ctx: &compend::gpu::GpuContext, wide: Option<[&str; 2]>) {
    use candle_core::Module;
    use compend::gpu::Photometric;
    use compend::model::Kind;

    let model = compennet_test_model(4);
    let p = Placement::for_model(&model, ImageSize::new(40, 30), DisplayRange::FULL).unwrap();
    let mut pass = CompensationPass::new(ctx, &model, p).unwrap();
    let content = random_content(7, 30, 20);
    pass.run(ctx, &content).unwrap();
    let Photometric::CompenNet(stage) = pass.photometric() else {
        panic!("a CompenNet++ model gets the CompenNet stage")
    };
    let Kind::CompenNet { simplified, .. } = &model.kind else {
        unreachable!()
    };
    let desired = playback::desired_view(&content, &p)
        .unwrap()
        .masked(&model.fov)
        .unwrap();
    let x = compend::nn::images_to_tensor(std::slice::from_ref(&desired)).unwrap();
    let x = compend::nn::grid_sample(&x, &simplified.grid).unwrap();
    // The forward pass of Backbone, spelled out (compend::nn::compennet::Backbone::forward).
    let (b, s) = (&simplified.backbone, &simplified.bias);
    let mut r = x.clone();
    let mut skip1 = Vec::new();
    for c in &b.skip1.convs {
        r = c.forward(&r).unwrap().relu().unwrap();
        skip1.push(r.clone());
    }
    let add_relu = |a: candle_core::Tensor, m: &candle_core::Tensor| {
        a.broadcast_add(m).unwrap().relu().unwrap()
    };
    let a1 = add_relu(b.conv1.forward(&x).unwrap(), &s.s1);
    let res2 = b.skip2.forward(&a1).unwrap();
    let a2 = add_relu(b.conv2.forward(&a1).unwrap(), &s.s2);
    let res3 = b.skip3.forward(&a2).unwrap();
    let a3 = add_relu(b.conv3.forward(&a2).unwrap(), &s.s3);
    let a4 = add_relu(b.conv4.forward(&a3).unwrap(), &s.s4);
    let a5 = add_relu(b.conv5.forward(&a4).unwrap(), &res3);
    let a6 = add_relu(b.tconv1.forward(&a5).unwrap(), &res2);
    let a7 = b.tconv2.forward(&a6).unwrap().relu().unwrap();
    let out = add_relu(b.conv6.forward(&a7).unwrap(), &skip1[2])
        .clamp(0.0, 1.0)
        .unwrap();
    let expected = [
        ("x", &x),
        ("skip1.0", &skip1[0]),
        ("skip1.1", &skip1[1]),
        ("res1", &skip1[2]),
        ("a1", &a1),
        ("res2", &res2),
        ("a2", &a2),
        ("res3", &res3),
        ("a3", &a3),
        ("a4", &a4),
        ("a5", &a5),
        ("a6", &a6),
        ("a7", &a7),
        ("out", &out),
    ];
    let mut names = vec!["x"];
    names.extend(stage.layer_names());
    assert_eq!(names, expected.map(|(n, _)| n));
    // The widths at the paper's base width 32: the skips and conv6 have 3 output channels, every
    // other layer 32 to 256; the transposed convolutions a6 and a7 (2×2, stride 2) their own
    // kernels.
    let timings = stage.kernel_timings();
    let mut timed = Vec::new();
    for (name, entry) in stage.layer_kernels() {
        let transposed = matches!(name, "a6" | "a7");
        let expect = match (name, wide) {
            ("skip1.0" | "skip1.1" | "res1" | "out", _) => "conv",
            (_, Some([conv, tconv])) => {
                if transposed {
                    tconv
                } else {
                    conv
                }
            }
            (_, None) => {
                // Measured: both kernels timed, the faster running.
                let (_, t) = timings
                    .iter()
                    .find(|(n, _)| *n == name)
                    .unwrap_or_else(|| panic!("layer {name}: no timings"));
                let entries: Vec<&str> = t.iter().map(|(e, _)| *e).collect();
                let both = if transposed {
                    ["tconv", "tconv_tiled"]
                } else {
                    ["conv", "conv_tiled"]
                };
                assert_eq!(entries, both, "layer {name}");
                assert!(
                    t.iter().all(|(_, ms)| ms.is_finite() && *ms >= 0.0),
                    "{t:?}"
                );
                timed.push(name);
                t.iter().min_by(|a, b| a.1.total_cmp(&b.1)).unwrap().0
            }
        };
        assert_eq!(entry, expect, "layer {name} ({:?})", ctx.conv);
    }
    let timed_names: Vec<_> = timings.iter().map(|(n, _)| *n).collect();
    assert_eq!(timed_names, timed, "layers timed ({:?})", ctx.conv);
    if wide.is_none() {
        eprintln!("measured kernels: {timings:?}");
        assert_eq!(
            timed.len(),
            9,
            "the wide convolutions a1..a5, res2, res3 and the transposed a6, a7"
        );
        // A second pass on the same device takes the choices timed for these shapes.
        let again = CompensationPass::new(ctx, &model, p).unwrap();
        let Photometric::CompenNet(again) = again.photometric() else {
            unreachable!()
        };
        assert_eq!(again.kernel_timings(), timings);
        assert_eq!(again.layer_kernels(), stage.layer_kernels());
    }
    for (name, t) in expected {
        let (c, h, w, gpu) = stage.read_activation(ctx, name).unwrap();
        assert_eq!(t.dims(), &[1, c, h, w], "{name}");
        let cpu: Vec<f32> = t.flatten_all().unwrap().to_vec1().unwrap();
        let scale = cpu.iter().fold(0f32, |m, v| m.max(v.abs()));
        let diff = cpu
            .iter()
            .zip(&gpu)
            .map(|(a, b)| (a - b).abs())
            .fold(0f32, f32::max);
        eprintln!(
            "{:?} layer {name} ({c}x{h}x{w}): max |Δ| {diff:.2e}, max |value| {scale:.2}",
            ctx.conv
        );
        assert!(
            diff <= 1e-4 * scale.max(1.0),
            "layer {name} differs by {diff}"
        );
    }
}

/// `compend play` with a CompenNet++ model through the real binary: a tiny simulated setup, two
/// training iterations (the weights do not matter here, the path does), three raw frames on the
/// virtual rig, each shown once and seen by the camera.
#[test]
fn compennet_model_plays_through_the_virtual_rig() {
    use crate::play::{count, play_with_stdin, raw_frames, tiny_model_with};

    if gpu().is_none() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let model = tiny_model_with(
        dir.path(),
        &[
            "--method",
            "compennet++-faster",
            "--iters",
            "2",
            "--batch",
            "2",
        ],
    );
    let meta: serde_json::Value =
        serde_json::from_slice(&std::fs::read(model.join("model.json")).unwrap()).unwrap();
    assert_eq!(meta["method"], "compennet++-faster");
    let out = dir.path().join("views");
    let (o, v) = play_with_stdin(
        &[
            "--model",
            model.to_str().unwrap(),
            "--source",
            "raw:-?size=40x30&format=rgb24",
            "--rig",
            "virtual",
            "--pace",
            "source",
            "--out",
            out.to_str().unwrap(),
            "--json",
        ],
        &raw_frames(3, 40, 30),
    );
    crate::common::assert_code(&o, 0);
    let v = v.unwrap();
    eprintln!("{v}");
    assert_eq!(count(&v, "received"), 3);
    assert_eq!(count(&v, "shown"), 3);
    assert_eq!(count(&v, "camera_views"), 3);
    assert!(out.join("cam_000003.png").is_file());
}

/// Two projectors of a set over a 48×40 camera: the first on its left two thirds, the second
/// on its right two thirds (a third overlapping), each with a per-pixel colour model of its
/// own gain, cross-talk and black level, so that bright and saturated desired values take the
/// bounded least squares.
fn joint_test_model(seed: u64) -> compend::joint::JointModel {
    use compend::linear::SimplifiedLinear;
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let net = ImageSize::new(30, 36);
    let models = [(0.0f32, 31.0f32, 0.45f32), (16.0, 47.0, 0.3)]
        .into_iter()
        .map(|(x0, x1, gain)| {
            let grid = Grid::<Network, Camera>::from_fn(net.width, net.height, |x, y| {
                let u = x0 + (x1 - x0) * x as f32 / (net.width - 1) as f32;
                let v = 1.0 + 37.0 * y as f32 / (net.height - 1) as f32;
                [pixel_to_norm(u, CAM.width), pixel_to_norm(v, CAM.height)]
            });
            let data = (0..net.width * net.height)
                .map(|_| {
                    // A = gain·(I + cross-talk); M = A⁻¹; b = −M·black.
                    let g = gain * rng.random_range(0.6..1.2f32);
                    let t = rng.random_range(0.0..0.08f32);
                    let a = [[g, g * t, 0.0], [g * t, g, g * t], [0.0, g * t, g]];
                    let m = compend::linear::gamut_inverse(&a).unwrap();
                    let black = rng.random_range(0.005..0.03f32);
                    let mut k = [0f32; 12];
                    for r in 0..3 {
                        k[r * 3..r * 3 + 3].copy_from_slice(&m[r]);
                        k[9 + r] = -(m[r][0] + m[r][1] + m[r][2]) * black;
                    }
                    k
                })
                .collect();
            SimplifiedLinear {
                grid,
                curves: Curves {
                    camera_gamma: [2.2, 2.1, 2.3],
                    projector_gamma: [2.0, 2.2, 2.4],
                },
                coeffs: Coefficients {
                    width: net.width,
                    height: net.height,
                    data,
                },
            }
        })
        .collect();
    compend::joint::JointModel::new(models, CAM).unwrap()
}

/// The joint pass of a set against its CPU reference (`JointModel::apply`): every projector's
/// image within 2e-4 (projector input values) at all but a handful of pixels where f32 rounding
/// tips the bounded least squares to another face (those within 5e-3), on desired views that
/// send much of the overlap through it.
#[test]
fn joint_pass_matches_the_cpu_reference() {
    let Some(ctx) = gpu() else { return };
    let joint = joint_test_model(5);
    let pass = compend::gpu::joint::JointPass::new(ctx, &joint).unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(17);
    for (i, top) in [0.6f32, 1.0].into_iter().enumerate() {
        let desired = Rgb::<Camera>::from_fn(CAM.width, CAM.height, |_, _| {
            [0, 1, 2].map(|_| rng.random_range(0.0..top))
        });
        pass.run(ctx, &desired).unwrap();
        let gpu_out = pass.read(ctx).unwrap();
        let cpu_out = joint.apply(&desired).unwrap();
        for (k, (g, c)) in gpu_out.iter().zip(&cpu_out).enumerate() {
            let diffs: Vec<f32> = g
                .data()
                .iter()
                .zip(c.data())
                .map(|(a, b)| (a - b).abs())
                .collect();
            let worst = diffs.iter().copied().fold(0.0, f32::max);
            let off = diffs.iter().filter(|&&d| d > 2e-4).count();
            eprintln!(
                "view {i} projector {}: max |Δ| {worst:.2e}, {off} of {} values over 2e-4",
                k + 1,
                diffs.len()
            );
            assert!(worst <= 5e-3, "projector {}: {worst}", k + 1);
            assert!(
                off * 200 <= diffs.len(),
                "projector {}: {off} values",
                k + 1
            );
        }
        // The bright view sends pixels through the bounded least squares: both projectors light
        // the overlap, and some of their light is at its bound there.
        if top == 1.0 {
            let at_bound = cpu_out
                .iter()
                .flat_map(|o| o.data().iter())
                .filter(|&&v| v >= 1.0 || v <= 0.0)
                .count();
            assert!(at_bound > 50, "{at_bound} values at a bound");
        }
    }
}
