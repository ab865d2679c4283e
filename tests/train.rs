//! `compend train`, `eval` and `compensate` through the real binary, on a synthetic setup written
//! in the dataset layout by the simulated system of `tests/linear.rs`.

use std::path::{Path, PathBuf};

use compend::dataset::{CaptureSet, DataRoot, ProjectorSet, Reference, Setup};
use compend::patterns::GrayCode;
use compend::raster::{NetImage, Rgb};
use rand::SeedableRng;
use rand::rngs::ChaCha8Rng;

use crate::common::{assert_code, compend, stderr, stdout};
use crate::linear::{NET, System, texture};

/// Writes ROOT/{train,test,sl} and ROOT/setup/cam/raw/{ref,train,test,sl} + cam/desire/test.
fn make_setup(dir: &Path, ntrain: usize, ntest: usize) -> PathBuf {
    let sys = System::new();
    let root = DataRoot::create(dir).unwrap();
    let setup = Setup::create(&root, Path::new("lab/pos1")).unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    for (set, cset, n) in [
        (ProjectorSet::Train, CaptureSet::Train, ntrain),
        (ProjectorSet::Test, CaptureSet::Test, ntest),
    ] {
        for i in 1..=n {
            let x = texture(&mut rng);
            root.write(set, i, &x.clone().into_space()).unwrap();
            setup.write_capture(cset, i, &sys.capture(&x)).unwrap();
        }
    }
    let flat = |v: f32| NetImage::filled(NET, NET, [v; 3]);
    setup
        .write_reference(Reference::Black, &sys.capture(&flat(0.0)))
        .unwrap();
    setup
        .write_reference(Reference::White, &sys.capture(&flat(1.0)))
        .unwrap();
    setup
        .write_reference(Reference::Gray, &sys.capture(&flat(77.0 / 255.0)))
        .unwrap();
    // Structured light with the projector frame = the network canvas.
    let code = GrayCode::new(NET, NET).unwrap();
    for i in 0..code.len() {
        let pat = code.pattern(i).unwrap();
        root.write(ProjectorSet::Sl, i + 1, &pat).unwrap();
        setup
            .write_capture(CaptureSet::Sl, i + 1, &sys.capture(&pat.into_space()))
            .unwrap();
    }
    // Desired images: the test images as a camera would ideally see them (a plain placement).
    for i in 1..=ntest {
        let x = root
            .load(ProjectorSet::Test, Some(i))
            .unwrap()
            .pop()
            .unwrap();
        let z =
            compend::resize::resize_bilinear(&x.into_space::<compend::raster::Camera>(), 48, 40);
        setup.write_desired(i, &z).unwrap();
    }
    setup.path().to_path_buf()
}

fn eval_json(model: &Path, setup: &Path) -> serde_json::Value {
    let out = compend(&[
        "eval",
        "--model",
        model.to_str().unwrap(),
        "--setup",
        setup.to_str().unwrap(),
        "--json",
    ]);
    assert_code(&out, 0);
    serde_json::from_str(stdout(&out).trim()).unwrap()
}

#[test]
fn train_eval_compensate_linear_and_linear_sl() {
    let dir = tempfile::tempdir().unwrap();
    let setup = make_setup(dir.path(), 16, 4);
    let s = setup.to_str().unwrap();
    for method in ["linear", "linear-sl"] {
        let model = dir.path().join(format!("model-{method}"));
        let m = model.to_str().unwrap();
        // `linear` on its default lattice (1.5× the network), `linear-sl` on the network's own.
        let (lattice, side) = if method == "linear" {
            (None, NET * 3 / 2)
        } else {
            (Some(NET.to_string()), NET)
        };
        let mut args = vec![
            "train", "--setup", s, "--method", method, "--out", m, "--json",
        ];
        if let Some(l) = &lattice {
            args.extend(["--lattice", l.as_str()]);
        }
        let out = compend(&args);
        assert_code(&out, 0);
        let summary: serde_json::Value = serde_json::from_str(stdout(&out).trim()).unwrap();
        assert_eq!(summary["method"], method);
        assert_eq!(summary["ntrain"], 16);
        assert!(model.join("model.safetensors").is_file() && model.join("model.json").is_file());

        let ev = eval_json(&model, &setup);
        let (c, u) = (
            ev["compensated"]["psnr"].as_f64().unwrap(),
            ev["uncompensated"]["psnr"].as_f64().unwrap(),
        );
        // The two-step baseline's geometry is limited by the 32-pixel Gray code here.
        let floor = if method == "linear" { 28.0 } else { 22.0 };
        assert!(
            c > floor && c > u + 5.0,
            "{method}: compensated {c:.2} dB vs uncompensated {u:.2} dB"
        );

        let cmp = setup.join(format!("prj/cmp/test/{method}"));
        let out = compend(&[
            "compensate",
            "--model",
            m,
            "--input",
            setup.join("cam/desire/test").to_str().unwrap(),
            "--out",
            cmp.to_str().unwrap(),
        ]);
        assert_code(&out, 0);
        for i in 1..=4 {
            let p = cmp.join(format!("img_{i:04}.png"));
            assert_eq!(
                compend::pngio::png_size(&p).unwrap(),
                (side, side),
                "{}",
                p.display()
            );
        }
    }
}

#[test]
fn bad_inputs_exit_2_and_keep_the_good_model() {
    let dir = tempfile::tempdir().unwrap();
    let setup = make_setup(dir.path(), 8, 2);
    let s = setup.to_str().unwrap();
    let model = dir.path().join("model");
    let m = model.to_str().unwrap();
    assert_code(
        &compend(&["train", "--setup", s, "--method", "linear", "--out", m]),
        0,
    );
    let before = std::fs::read(model.join("model.safetensors")).unwrap();

    // More training pairs than exist: exit 2, names the folder and the counts; model untouched.
    let out = compend(&[
        "train", "--setup", s, "--method", "linear", "--ntrain", "50", "--out", m,
    ]);
    assert_code(&out, 2);
    assert!(
        stderr(&out).contains("cam/raw/train") && stderr(&out).contains("50"),
        "{}",
        stderr(&out)
    );
    assert_eq!(
        std::fs::read(model.join("model.safetensors")).unwrap(),
        before
    );

    // Unknown method.
    let out = compend(&["train", "--setup", s, "--method", "magic", "--out", m]);
    assert_code(&out, 2);
    assert!(stderr(&out).contains("magic"), "{}", stderr(&out));

    // A lattice too small, or one for a method that has none.
    for (method, lattice) in [("linear", "4x64"), ("compennet++-faster", "48")] {
        let out = compend(&[
            "train",
            "--setup",
            s,
            "--method",
            method,
            "--lattice",
            lattice,
            "--out",
            m,
        ]);
        assert_code(&out, 2);
        assert!(stderr(&out).contains("--lattice"), "{}", stderr(&out));
    }
    assert_eq!(
        std::fs::read(model.join("model.safetensors")).unwrap(),
        before
    );

    // A missing or mismatched photometric pre-initialisation names the file.
    let weights = dir.path().join("w4.safetensors");
    let tiny = compend::nn::pretrain::PretrainSettings {
        width: 4,
        patch: 16,
        image: 16,
        pool: 1,
        batch: 1,
        iters: 1,
        lr_step: 1,
        learning_rate: 1e-3,
        weight_decay: 0.0,
        seed: 0,
    };
    let never = std::sync::atomic::AtomicBool::new(false);
    compend::nn::pretrain::pretrain(&tiny, &candle_core::Device::Cpu, &never, |_, _, _| {})
        .unwrap()
        .save(&weights)
        .unwrap();
    for (file, says) in [
        ("absent.safetensors", "absent.safetensors"),
        ("w4.safetensors", "width 4"),
    ] {
        let path = dir.path().join(file);
        let out = compend(&[
            "train",
            "--setup",
            s,
            "--method",
            "compennet++-faster",
            "--photometric-init",
            path.to_str().unwrap(),
            "--out",
            m,
        ]);
        assert_code(&out, 2);
        assert!(stderr(&out).contains(says), "{}", stderr(&out));
    }
    assert_eq!(
        std::fs::read(model.join("model.safetensors")).unwrap(),
        before
    );

    // A missing reference capture names the file.
    let white = setup.join("cam/raw/ref/img_0125.png");
    std::fs::remove_file(&white).unwrap();
    let out = compend(&["train", "--setup", s, "--method", "linear", "--out", m]);
    assert_code(&out, 2);
    assert!(stderr(&out).contains("img_0125.png"), "{}", stderr(&out));
    assert_eq!(
        std::fs::read(model.join("model.safetensors")).unwrap(),
        before
    );

    // A corrupt model file, an old format version, a missing model: exit 2 naming the file.
    let bad = dir.path().join("bad-model");
    std::fs::create_dir_all(&bad).unwrap();
    std::fs::copy(model.join("model.json"), bad.join("model.json")).unwrap();
    std::fs::write(bad.join("model.safetensors"), b"not a tensor file").unwrap();
    let out = compend(&["eval", "--model", bad.to_str().unwrap(), "--setup", s]);
    assert_code(&out, 2);
    assert!(
        stderr(&out).contains("model.safetensors"),
        "{}",
        stderr(&out)
    );

    let json = std::fs::read_to_string(model.join("model.json")).unwrap();
    std::fs::write(
        bad.join("model.json"),
        json.replace("\"format_version\": 1", "\"format_version\": 0"),
    )
    .unwrap();
    std::fs::copy(
        model.join("model.safetensors"),
        bad.join("model.safetensors"),
    )
    .unwrap();
    let out = compend(&["eval", "--model", bad.to_str().unwrap(), "--setup", s]);
    assert_code(&out, 2);
    assert!(stderr(&out).contains("version 0"), "{}", stderr(&out));

    let out = compend(&[
        "compensate",
        "--model",
        dir.path().join("nope").to_str().unwrap(),
        "--input",
        s,
        "--out",
        s,
    ]);
    assert_code(&out, 2);

    // A desired image of the wrong size names the file and both sizes.
    let wrong = dir.path().join("wrong.png");
    compend::pngio::write_rgb(&wrong, &Rgb::<compend::raster::Camera>::new(10, 10)).unwrap();
    let out = compend(&[
        "compensate",
        "--model",
        m,
        "--input",
        wrong.to_str().unwrap(),
        "--out",
        dir.path().join("o").to_str().unwrap(),
    ]);
    assert_code(&out, 2);
    assert!(
        stderr(&out).contains("wrong.png") && stderr(&out).contains("48x40"),
        "{}",
        stderr(&out)
    );
}

#[test]
fn inspect_reports_the_fov_and_display_area() {
    let dir = tempfile::tempdir().unwrap();
    let setup = make_setup(dir.path(), 4, 1);
    let out_dir = dir.path().join("inspect");
    let out = compend(&[
        "inspect",
        "--setup",
        setup.to_str().unwrap(),
        "--json",
        "--out",
        out_dir.to_str().unwrap(),
    ]);
    assert_code(&out, 0);
    let r: serde_json::Value = serde_json::from_str(stdout(&out).trim()).unwrap();
    let fov = &r["fov"];
    // The simulated projector covers the central ~80% of the 48x40 camera frame.
    let cov = fov["coverage"].as_f64().unwrap();
    assert!(cov > 0.5 && cov < 0.9, "coverage {cov}");
    let area = &fov["displayable_area"];
    let (w, h) = (
        area["width"].as_u64().unwrap(),
        area["height"].as_u64().unwrap(),
    );
    assert!(
        (w as i64 - h as i64).abs() <= 1,
        "square canvas → square area, got {w}x{h}"
    );
    let mask = compend::pngio::read_mask::<compend::raster::Camera>(&out_dir.join("fov_mask.png"))
        .unwrap();
    assert_eq!(mask.size(), (48, 40));
    assert!(out_dir.join("fov_overlay.png").is_file());
}

#[test]
fn compennet_trains_saves_loads_and_compensates_through_the_cli() {
    let dir = tempfile::tempdir().unwrap();
    let setup = make_setup(dir.path(), 12, 3);
    let s = setup.to_str().unwrap();
    // The two-step baseline: CompenNet on structured-light geometry, saved with its fixed grid.
    let sl = dir.path().join("cnn-sl");
    let out = compend(&[
        "train",
        "--setup",
        s,
        "--method",
        "compennet-sl",
        "--iters",
        "80",
        "--batch",
        "4",
        "--out",
        sl.to_str().unwrap(),
    ]);
    assert_code(&out, 0);
    let ev = eval_json(&sl, &setup);
    let (c, u) = (
        ev["compensated"]["psnr"].as_f64().unwrap(),
        ev["uncompensated"]["psnr"].as_f64().unwrap(),
    );
    assert!(c > u, "compennet-sl {c:.2} dB vs uncompensated {u:.2} dB");
    let (_, t) = compend::model::store::load(&sl).unwrap();
    assert!(t.names().any(|n| n == "warp.grid") && !t.names().any(|n| n == "warp.theta"));

    let model = dir.path().join("cnn");
    let m = model.to_str().unwrap();
    let out = compend(&[
        "train",
        "--setup",
        s,
        "--method",
        "compennet++-faster",
        "--iters",
        "40",
        "--batch",
        "4",
        "--out",
        m,
        "--json",
    ]);
    assert_code(&out, 0);
    let summary: serde_json::Value = serde_json::from_str(stdout(&out).trim()).unwrap();
    assert_eq!(
        summary["ntrain"], 12,
        "the variant's 48 capped at the 12 available"
    );
    let meta: serde_json::Value =
        serde_json::from_slice(&std::fs::read(model.join("model.json")).unwrap()).unwrap();
    assert_eq!(meta["method"], "compennet++-faster");
    assert_eq!(meta["training"]["iterations"], 40);
    assert_eq!(meta["training"]["lr_step"], 32);
    assert_eq!(
        meta["training"]["photometric_init"],
        "shipped:weights/compennet-pretrain-w32.safetensors"
    );

    // Loading runs the full network; the score is deterministic and the compensated row beats the
    // captures warped as they are.
    let ev = eval_json(&model, &setup);
    let (c, u) = (
        ev["compensated"]["psnr"].as_f64().unwrap(),
        ev["uncompensated"]["psnr"].as_f64().unwrap(),
    );
    assert!(c > u, "compennet++ {c:.2} dB vs uncompensated {u:.2} dB");
    assert_eq!(eval_json(&model, &setup)["compensated"], ev["compensated"]);

    let cmp = dir.path().join("cmp");
    let out = compend(&[
        "compensate",
        "--model",
        m,
        "--input",
        setup.join("cam/desire/test").to_str().unwrap(),
        "--out",
        cmp.to_str().unwrap(),
    ]);
    assert_code(&out, 0);
    assert_eq!(
        compend::pngio::png_size(&cmp.join("img_0001.png")).unwrap(),
        (NET, NET)
    );

    // The CPU rung: half the network side and half the widths; it loads back at its own size,
    // is scored at the data's network size and writes images of its own size.
    let small = dir.path().join("cnn-cpu");
    let out = compend(&[
        "train",
        "--setup",
        s,
        "--method",
        "compennet++-cpu",
        "--iters",
        "150",
        "--batch",
        "4",
        "--out",
        small.to_str().unwrap(),
    ]);
    assert_code(&out, 0);
    let meta: serde_json::Value =
        serde_json::from_slice(&std::fs::read(small.join("model.json")).unwrap()).unwrap();
    assert_eq!(meta["network_size"], serde_json::json!([NET / 2, NET / 2]));
    let ev = eval_json(&small, &setup);
    let (c, u) = (
        ev["compensated"]["psnr"].as_f64().unwrap(),
        ev["uncompensated"]["psnr"].as_f64().unwrap(),
    );
    assert!(
        c > u,
        "compennet++-cpu {c:.2} dB vs uncompensated {u:.2} dB"
    );
    let cmp_small = dir.path().join("cmp-cpu");
    let out = compend(&[
        "compensate",
        "--model",
        small.to_str().unwrap(),
        "--input",
        setup.join("cam/desire/test").to_str().unwrap(),
        "--out",
        cmp_small.to_str().unwrap(),
    ]);
    assert_code(&out, 0);
    assert_eq!(
        compend::pngio::png_size(&cmp_small.join("img_0001.png")).unwrap(),
        (NET / 2, NET / 2)
    );

    // A tensor of the wrong shape in the weights: exit 2 naming the tensor.
    let (meta, mut tensors) = compend::model::store::load(&model).unwrap();
    tensors
        .insert("compen.backbone.conv6.bias", vec![4], vec![0.0; 4])
        .unwrap();
    let bad = dir.path().join("bad");
    compend::model::store::save(&bad, &meta, &tensors).unwrap();
    let out = compend(&["eval", "--model", bad.to_str().unwrap(), "--setup", s]);
    assert_code(&out, 2);
    assert!(
        stderr(&out).contains("compen.backbone.conv6.bias"),
        "{}",
        stderr(&out)
    );
}

#[test]
fn train_device_is_checked_before_any_work() {
    let dir = tempfile::tempdir().unwrap();
    let setup = make_setup(dir.path(), 6, 1);
    let s = setup.to_str().unwrap();
    let model = dir.path().join("m");
    // A spelling that is no device is a usage error naming the accepted ones.
    let out = compend(&[
        "train",
        "--setup",
        s,
        "--method",
        "compennet++-faster",
        "--device",
        "gpu",
    ]);
    assert_code(&out, 2);
    assert!(stderr(&out).contains("cuda:N"), "{}", stderr(&out));
    // This build has no CUDA (CI never enables the feature): a clear input error, no model.
    if !cfg!(feature = "cuda") {
        let out = compend(&[
            "train",
            "--setup",
            s,
            "--method",
            "compennet++-faster",
            "--device",
            "cuda",
            "--out",
            model.to_str().unwrap(),
        ]);
        assert_code(&out, 2);
        assert!(stderr(&out).contains("--features cuda"), "{}", stderr(&out));
        assert!(!model.exists());
    }
    // `--device cpu` is accepted by every method (the linear rungs always fit on the CPU).
    let out = compend(&[
        "train",
        "--setup",
        s,
        "--method",
        "linear",
        "--device",
        "cpu",
        "--out",
        model.to_str().unwrap(),
    ]);
    assert_code(&out, 0);
}

#[test]
fn auto_picks_the_linear_rung_with_the_best_held_out_score_and_records_why() {
    let dir = tempfile::tempdir().unwrap();
    let setup = make_setup(dir.path(), 16, 2);
    let s = setup.to_str().unwrap();
    let model = dir.path().join("auto");
    let out = compend(&[
        "train",
        "--setup",
        s,
        "--method",
        "auto",
        "--out",
        model.to_str().unwrap(),
        "--json",
    ]);
    assert_code(&out, 0);
    let summary: serde_json::Value = serde_json::from_str(stdout(&out).trim()).unwrap();
    let meta: serde_json::Value =
        serde_json::from_slice(&std::fs::read(model.join("model.json")).unwrap()).unwrap();
    let auto = &meta["training"]["auto"];
    let cands = auto["candidates"].as_array().unwrap();
    let methods: Vec<&str> = cands
        .iter()
        .map(|c| c["method"].as_str().unwrap())
        .collect();
    assert_eq!(methods, ["linear", "linear-sl"], "{auto}");
    assert_eq!(auto["held_out"], 4);
    assert_eq!(auto["fitted_on"], 12);
    // The choice is the candidate with the highest held-out PSNR, and it is what was saved.
    let best = cands
        .iter()
        .max_by(|a, b| {
            let p = |c: &serde_json::Value| c["held_out_psnr"].as_f64().unwrap();
            p(a).total_cmp(&p(b))
        })
        .unwrap();
    assert_eq!(auto["chosen"], best["method"]);
    assert_eq!(meta["method"], best["method"]);
    assert_eq!(summary["method"], best["method"]);
    // The saved model loads and runs like any linear model.
    let ev = eval_json(&model, &setup);
    assert!(
        ev["compensated"]["psnr"].as_f64().unwrap() > ev["uncompensated"]["psnr"].as_f64().unwrap()
    );

    // Without structured-light captures, `linear` is the only candidate, and the record says so.
    std::fs::remove_dir_all(setup.join("cam/raw/sl")).unwrap();
    let out = compend(&[
        "train",
        "--setup",
        s,
        "--method",
        "auto",
        "--out",
        model.to_str().unwrap(),
        "--json",
    ]);
    assert_code(&out, 0);
    let meta: serde_json::Value =
        serde_json::from_slice(&std::fs::read(model.join("model.json")).unwrap()).unwrap();
    assert_eq!(meta["method"], "linear");
    let why = meta["training"]["auto"]["why"].as_str().unwrap();
    assert!(why.contains("structured-light"), "{why}");
}
