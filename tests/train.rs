//! `compend train`, `eval` and `compensate` through the real binary, on a synthetic setup written
//! in the dataset layout by the simulated system of `tests/linear.rs`: every rung trains, saves,
//! loads, scores and compensates. Their refusals of bad input are in `tests/train_cli.rs`.

use std::path::{Path, PathBuf};

use compend::dataset::{CaptureSet, DataRoot, ProjectorSet, Reference, Setup};
use compend::patterns::GrayCode;
use compend::raster::{ImageSize, NetImage};
use rand::SeedableRng;
use rand::rngs::ChaCha8Rng;

use crate::common::{assert_code, compend, stderr, stdout, train_linear};
use crate::linear::{NET, System, texture};

/// Writes ROOT/{train,test,sl} and ROOT/setup/cam/raw/{ref,train,test,sl} + cam/desire/test.
pub(crate) fn make_setup(dir: &Path, ntrain: usize, ntest: usize) -> PathBuf {
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
        // `linear` on its default lattice (the projector's resolution: the fixture's structured
        // light is NET×NET), `linear-sl` on a finer one asked for.
        let (lattice, side) = if method == "linear" {
            (None, NET)
        } else {
            (Some((NET * 3 / 2).to_string()), NET * 3 / 2)
        };
        let mut args = vec![
            "train", "--setup", s, "--method", method, "--out", m, "--json",
        ];
        if let Some(l) = &lattice {
            args.extend(["--lattice", l.as_str()]);
        }
        let out = compend(&args);
        assert_code(&out, 0);
        // Which lattice, and why, is said.
        let said = match &lattice {
            None => format!(
                "output lattice {NET}x{NET}: the projector's resolution, {NET}x{NET} (the \
                 structured-light patterns' size)"
            ),
            Some(l) => format!("output lattice {l}x{l}: as asked (--lattice)"),
        };
        assert!(stderr(&out).contains(&said), "{}", stderr(&out));
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
                ImageSize::new(side, side),
                "{}",
                p.display()
            );
        }
    }
    // `compensate` replaces its own earlier images, but never the inputs or someone else's
    // files of the same names, and an --out that is a file is refused: each exits 2, naming
    // the path, and leaves the files as they were.
    let m = dir.path().join("model-linear");
    let desire = setup.join("cam/desire/test");
    let run = |out: &Path| {
        compend(&[
            "compensate",
            "--model",
            m.to_str().unwrap(),
            "--input",
            desire.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ])
    };
    assert_code(&run(&setup.join("prj/cmp/test/linear")), 0);
    let theirs = dir.path().join("theirs");
    std::fs::create_dir(&theirs).unwrap();
    std::fs::write(theirs.join("img_0002.png"), b"mine").unwrap();
    let file = dir.path().join("notes.txt");
    std::fs::write(&file, b"mine").unwrap();
    let inputs: Vec<Vec<u8>> = (1..=4)
        .map(|i| std::fs::read(desire.join(format!("img_{i:04}.png"))).unwrap())
        .collect();
    for (out, says) in [
        (&desire, "would replace the inputs"),
        (&theirs, "not written by `compend compensate`"),
        (&file, "not a folder; it takes the folder"),
    ] {
        let o = run(out);
        assert_code(&o, 2);
        assert!(
            stderr(&o).contains(out.to_str().unwrap()) && stderr(&o).contains(says),
            "{}",
            stderr(&o)
        );
    }
    assert_eq!(std::fs::read(theirs.join("img_0002.png")).unwrap(), b"mine");
    assert_eq!(std::fs::read(&file).unwrap(), b"mine");
    for (i, bytes) in inputs.iter().enumerate() {
        let p = desire.join(format!("img_{:04}.png", i + 1));
        assert_eq!(&std::fs::read(&p).unwrap(), bytes, "{}", p.display());
    }
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
    assert_eq!(mask.size(), ImageSize::new(48, 40));
    assert!(out_dir.join("fov_overlay.png").is_file());
}

#[test]
fn compennet_trains_saves_loads_and_compensates_through_the_cli() {
    let dir = tempfile::tempdir().unwrap();
    let setup = make_setup(dir.path(), 12, 3);
    compennet_sl_saves_its_fixed_grid(dir.path(), &setup);
    let model = compennet_faster_trains_and_compensates(dir.path(), &setup);
    compennet_cpu_works_at_half_the_network_side(dir.path(), &setup);
    residual_rung_starts_where_linear_ends(dir.path(), &setup);
    wrong_tensor_shape_names_the_tensor(dir.path(), &model, &setup);
}

/// `compennet++-res`: after one step it is `linear` (its correction starts at zero), its
/// images are on linear's lattice, and after a short training it is no worse than `linear`.
fn residual_rung_starts_where_linear_ends(dir: &Path, setup: &Path) {
    let linear = dir.join("linear-for-res");
    assert_code(&train_linear(setup, &linear), 0);
    let (lin, _) = compensated_and_uncompensated(&eval_json(&linear, setup));
    let res1 = dir.join("res-1");
    train_cnn(setup, "compennet++-res", "1", &res1, false);
    let meta = model_json(&res1);
    // The model's output lattice is linear's (by default the projector's resolution, NET×NET
    // here), not the network's half.
    assert_eq!(meta["network_size"], serde_json::json!([NET, NET]));
    assert_eq!(
        meta["training"]["geometry_init"],
        "the linear rung's grid (fixed)"
    );
    // Without closed-loop pairs the correction learns the paper protocol's target.
    let correction = meta["training"]["correction"].as_str().unwrap();
    assert!(
        correction.starts_with("12 pairs, paper protocol"),
        "{correction}"
    );
    let (one, _) = compensated_and_uncompensated(&eval_json(&res1, setup));
    assert!(
        (one - lin).abs() < 0.3,
        "after one step compennet++-res {one:.2} dB, linear {lin:.2} dB"
    );
    let res = dir.join("res-60");
    train_cnn(setup, "compennet++-res", "60", &res, false);
    let (trained, u) = compensated_and_uncompensated(&eval_json(&res, setup));
    assert!(
        trained > lin - 0.3 && trained > u,
        "compennet++-res {trained:.2} dB, linear {lin:.2} dB, uncompensated {u:.2} dB"
    );
    let cmp = dir.join("cmp-res");
    compensate(&res, setup, &cmp);
    assert_eq!(
        compend::pngio::png_size(&cmp.join("img_0001.png")).unwrap(),
        ImageSize::new(NET, NET)
    );
    // The full-size residual rung (`auto`'s climb on a GPU) starts at `linear` too, with the
    // paper's widths on the whole network side where `compennet++-res` has half of each.
    let full = dir.join("res-full-1");
    train_cnn(setup, "compennet++-res-full", "1", &full, false);
    assert_eq!(model_json(&full)["method"], "compennet++-res-full");
    let grid = compend::nn::compennetpp::FIXED_GRID;
    assert_eq!(tensor_shape(&res1, grid), [1, NET / 2, NET / 2, 2]);
    assert_eq!(tensor_shape(&full, grid), [1, NET, NET, 2]);
    assert_eq!(tensor_shape(&res1, "compen.backbone.conv1.weight")[0], 16);
    assert_eq!(tensor_shape(&full, "compen.backbone.conv1.weight")[0], 32);
    let (one_full, _) = compensated_and_uncompensated(&eval_json(&full, setup));
    assert!(
        (one_full - lin).abs() < 0.3,
        "after one step compennet++-res-full {one_full:.2} dB, linear {lin:.2} dB"
    );
    // Its linear part takes --lattice as the linear rungs do.
    let fine = dir.join("res-lattice");
    let out = compend(&[
        "train",
        "--setup",
        setup.to_str().unwrap(),
        "--method",
        "compennet++-res",
        "--iters",
        "1",
        "--lattice",
        "40",
        "--out",
        fine.to_str().unwrap(),
    ]);
    assert_code(&out, 0);
    let meta = model_json(&fine);
    assert_eq!(meta["network_size"], serde_json::json!([40, 40]));
}

/// The shape of tensor `name` in a model directory's weights.
fn tensor_shape(model: &Path, name: &str) -> Vec<usize> {
    let bytes = std::fs::read(model.join("model.safetensors")).unwrap();
    let tensors = safetensors::SafeTensors::deserialize(&bytes).unwrap();
    let names = tensors.names();
    let t = tensors
        .tensor(name)
        .unwrap_or_else(|e| panic!("{name}: {e}; tensors: {names:?}"));
    t.shape().to_vec()
}

/// A model directory's `model.json`.
fn model_json(model: &Path) -> serde_json::Value {
    serde_json::from_slice(&std::fs::read(model.join("model.json")).unwrap()).unwrap()
}

/// Trains `method` through the CLI with `--iters` and batch 4 into `out`, expecting success;
/// returns the command's stdout.
fn train_cnn(setup: &Path, method: &str, iters: &str, out: &Path, json: bool) -> String {
    let mut args = vec![
        "train",
        "--setup",
        setup.to_str().unwrap(),
        "--method",
        method,
        "--iters",
        iters,
        "--batch",
        "4",
        "--out",
        out.to_str().unwrap(),
    ];
    if json {
        args.push("--json");
    }
    let out = compend(&args);
    assert_code(&out, 0);
    stdout(&out)
}

/// PSNRs (dB) of the compensated and uncompensated rows of `compend eval`.
fn compensated_and_uncompensated(ev: &serde_json::Value) -> (f64, f64) {
    (
        ev["compensated"]["psnr"].as_f64().unwrap(),
        ev["uncompensated"]["psnr"].as_f64().unwrap(),
    )
}

/// The two-step baseline: CompenNet on structured-light geometry, saved with its fixed grid.
fn compennet_sl_saves_its_fixed_grid(dir: &Path, setup: &Path) {
    let sl = dir.join("cnn-sl");
    train_cnn(setup, "compennet-sl", "80", &sl, false);
    let (c, u) = compensated_and_uncompensated(&eval_json(&sl, setup));
    assert!(c > u, "compennet-sl {c:.2} dB vs uncompensated {u:.2} dB");
    let (_, t) = compend::model::store::load(&sl).unwrap();
    assert!(t.names().any(|n| n == "warp.grid") && !t.names().any(|n| n == "warp.theta"));
}

/// `compennet++-faster`: its record, a deterministic score above the uncompensated row, and
/// compensation images at the network size. Returns the model's folder.
fn compennet_faster_trains_and_compensates(dir: &Path, setup: &Path) -> PathBuf {
    let model = dir.join("cnn");
    let out = train_cnn(setup, "compennet++-faster", "40", &model, true);
    let summary: serde_json::Value = serde_json::from_str(out.trim()).unwrap();
    assert_eq!(
        summary["ntrain"], 12,
        "the variant's 48 capped at the 12 available"
    );
    let meta = model_json(&model);
    assert_eq!(meta["method"], "compennet++-faster");
    assert_eq!(meta["training"]["iterations"], 40);
    assert_eq!(meta["training"]["lr_step"], 32);
    assert_eq!(
        meta["training"]["photometric_init"],
        "shipped:weights/compennet-pretrain-w32.safetensors"
    );

    // Loading runs the full network; the score is deterministic and the compensated row beats the
    // captures warped as they are.
    let ev = eval_json(&model, setup);
    let (c, u) = compensated_and_uncompensated(&ev);
    assert!(c > u, "compennet++ {c:.2} dB vs uncompensated {u:.2} dB");
    assert_eq!(eval_json(&model, setup)["compensated"], ev["compensated"]);

    let cmp = dir.join("cmp");
    compensate(&model, setup, &cmp);
    assert_eq!(
        compend::pngio::png_size(&cmp.join("img_0001.png")).unwrap(),
        ImageSize::new(NET, NET)
    );
    model
}

/// `compend compensate` of the setup's desired images into `out`, expecting success.
fn compensate(model: &Path, setup: &Path, out: &Path) {
    let out = compend(&[
        "compensate",
        "--model",
        model.to_str().unwrap(),
        "--input",
        setup.join("cam/desire/test").to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert_code(&out, 0);
}

/// The CPU rung: half the network side and half the widths; it loads back at its own size, is
/// scored at the data's network size and writes images of its own size.
fn compennet_cpu_works_at_half_the_network_side(dir: &Path, setup: &Path) {
    let small = dir.join("cnn-cpu");
    train_cnn(setup, "compennet++-cpu", "150", &small, false);
    let meta = model_json(&small);
    assert_eq!(meta["network_size"], serde_json::json!([NET / 2, NET / 2]));
    let (c, u) = compensated_and_uncompensated(&eval_json(&small, setup));
    assert!(
        c > u,
        "compennet++-cpu {c:.2} dB vs uncompensated {u:.2} dB"
    );
    let cmp_small = dir.join("cmp-cpu");
    compensate(&small, setup, &cmp_small);
    assert_eq!(
        compend::pngio::png_size(&cmp_small.join("img_0001.png")).unwrap(),
        ImageSize::new(NET / 2, NET / 2)
    );
}

/// A tensor of the wrong shape in the weights: exit 2 naming the tensor.
fn wrong_tensor_shape_names_the_tensor(dir: &Path, model: &Path, setup: &Path) {
    let (meta, mut tensors) = compend::model::store::load(model).unwrap();
    tensors
        .insert("compen.backbone.conv6.bias", vec![4], vec![0.0; 4])
        .unwrap();
    let bad = dir.join("bad");
    compend::model::store::save(&bad, &meta, &tensors).unwrap();
    let out = compend(&[
        "eval",
        "--model",
        bad.to_str().unwrap(),
        "--setup",
        setup.to_str().unwrap(),
    ]);
    assert_code(&out, 2);
    assert!(
        stderr(&out).contains("compen.backbone.conv6.bias"),
        "{}",
        stderr(&out)
    );
}

/// `compend train --method auto` on the test setup with extra flags; the model's `training.auto`.
fn train_auto(setup: &Path, model: &Path, extra: &[&str]) -> serde_json::Value {
    let mut args = vec![
        "train",
        "--setup",
        setup.to_str().unwrap(),
        "--method",
        "auto",
        "--out",
        model.to_str().unwrap(),
        "--json",
    ];
    args.extend_from_slice(extra);
    let out = compend(&args);
    assert_code(&out, 0);
    let summary: serde_json::Value = serde_json::from_str(stdout(&out).trim()).unwrap();
    let meta = model_json(model);
    // What was chosen is what was saved and reported.
    assert_eq!(meta["method"], meta["training"]["auto"]["chosen"], "{meta}");
    assert_eq!(summary["method"], meta["method"]);
    meta
}

#[test]
fn auto_climbs_the_ladder_only_as_far_as_held_out_pairs_show_a_gain_and_records_why() {
    let dir = tempfile::tempdir().unwrap();
    let setup = make_setup(dir.path(), 16, 2);
    let model = dir.path().join("auto");
    // The residual rung trained for 3 iterations is still `linear`: no gain of 0.5 dB.
    let meta = train_auto(&setup, &model, &["--iters", "3"]);
    let auto = &meta["training"]["auto"];
    let cands = auto["candidates"].as_array().unwrap();
    let methods: Vec<&str> = cands
        .iter()
        .map(|c| c["method"].as_str().unwrap())
        .collect();
    assert_eq!(
        methods,
        ["linear", "linear-sl", "compennet++-res"],
        "{auto}"
    );
    assert_eq!(auto["held_out"], 4);
    assert_eq!(auto["fitted_on"], 12);
    assert_eq!(auto["required_gain_db"], 0.5);
    let psnr = |c: &serde_json::Value| c["held_out_psnr"].as_f64().unwrap();
    assert!(
        cands
            .iter()
            .all(|c| c["fit_seconds"].as_f64().unwrap() > 0.0)
    );
    // The choice is the linear candidate with the highest held-out PSNR.
    let best_linear = cands[..2]
        .iter()
        .max_by(|a, b| psnr(a).total_cmp(&psnr(b)))
        .unwrap();
    assert!(psnr(&cands[2]) < psnr(best_linear) + 0.5, "{auto}");
    assert_eq!(auto["chosen"], best_linear["method"]);
    // The saved model loads and runs like any linear model, refitted on all 16 pairs.
    assert_eq!(meta["training"]["ntrain"], 16);
    let ev = eval_json(&model, &setup);
    assert!(
        ev["compensated"]["psnr"].as_f64().unwrap() > ev["uncompensated"]["psnr"].as_f64().unwrap()
    );

    // With no margin to clear, the CompenNet++ rung climbs. Judged as it trained on the 12
    // pairs (a checkpoint per iteration here; a margin below zero never settles, so it ran to
    // its end), it is then trained again on all 16 pairs, the model kept.
    let climbed = dir.path().join("climbed");
    let meta = train_auto(&setup, &climbed, &["--iters", "3", "--climb-gain", "-1000"]);
    assert_eq!(meta["method"], "compennet++-res", "{meta}");
    let auto = &meta["training"]["auto"];
    assert_eq!(auto["required_gain_db"], -1000.0);
    let judged = &auto["judged"];
    assert!(judged.get("settled_at").is_none(), "{auto}");
    assert!(judged.get("stopped_at").is_none(), "{auto}");
    assert_eq!(judged["iterations"], 3, "{auto}");
    let curve = judged["curve"].as_array().unwrap();
    assert_eq!(curve.len(), 4, "{auto}");
    // The curve starts at the rung's own `linear` (its correction at zero), which matches
    // the `linear` candidate fitted on the same pairs; its figure is the last checkpoint.
    let cands = auto["candidates"].as_array().unwrap();
    let rung = &cands[2];
    assert_eq!(rung["method"], "compennet++-res", "{auto}");
    assert_eq!(curve[3]["psnr"], rung["held_out_psnr"], "{auto}");
    let at = |c: &serde_json::Value| c["psnr"].as_f64().unwrap();
    assert!((at(&curve[0]) - psnr(&cands[0])).abs() < 1e-6, "{auto}");
    assert_eq!(auto["retrained"]["pairs"], 16, "{auto}");
    assert_eq!(auto["retrained"]["method"], "compennet++-res", "{auto}");
    assert!(
        auto["retrained"]["seconds"].as_f64().unwrap() > 0.0,
        "{auto}"
    );
    assert_eq!(meta["training"]["ntrain"], 16);
    assert_eq!(meta["training"]["iterations"], 3);
    eval_json(&climbed, &setup);
    // It is the model `--method compennet++-res` trains on those pairs with that seed, to the
    // byte.
    // The residual rung trained alone with `args` (its count of pairs, iterations, seed), into
    // `out`.
    let res_on = |args: &[&str], out: &Path| {
        let o = compend(
            &[
                &["train", "--setup", setup.to_str().unwrap()][..],
                &[
                    "--method",
                    "compennet++-res",
                    "--out",
                    out.to_str().unwrap(),
                ],
                args,
            ]
            .concat(),
        );
        assert_code(&o, 0);
    };
    let res = dir.path().join("res");
    res_on(&["--iters", "3", "--ntrain", "16"], &res);
    let weights = |m: &Path| std::fs::read(m.join("model.safetensors")).unwrap();
    assert!(
        weights(&res) == weights(&climbed),
        "the climbed model differs from the rung's"
    );
    // The judgement scores the rung as inference runs it: the rung trained on the 12 pairs it
    // was judged after (the same weights: the judged training ran to its end) gives, by the
    // paper protocol on the 4 held-out pairs, the judgement's last figure. Its correction is
    // not zero after 3 iterations, so this checks the correction's path too.
    let judged_rung = dir.path().join("judged");
    res_on(&["--iters", "3", "--ntrain", "12"], &judged_rung);
    let judged_model = compend::model::Model::load(&judged_rung).unwrap();
    let mut pairs = compend::dataset::Setup::open(&setup, None)
        .unwrap()
        .load_train(Some(16))
        .unwrap();
    pairs.captures.drain(..12);
    pairs.inputs.drain(..12);
    let (scored, _) = compend::model::paper_protocol(&judged_model, &pairs).unwrap();
    assert!(
        (scored.psnr - at(&curve[3])).abs() < 1e-3,
        "held-out {} dB by the judgement, {} by inference",
        at(&curve[3]),
        scored.psnr
    );
    assert!((at(&curve[3]) - at(&curve[0])).abs() > 1e-4, "{auto}");

    // A margin of zero, which the rung's gain reaches early (with seed 3): its judged training
    // stops once the gain has been at or past it at two checkpoints after the start (settled),
    // before the end of its 8 iterations, and the rung climbs. The model kept is the rung
    // trained again from its start for all 8 iterations on all 16 pairs, to the byte.
    let settled = dir.path().join("settled");
    let args = ["--iters", "8", "--seed", "3"];
    let meta = train_auto(
        &setup,
        &settled,
        &[&args[..], &["--climb-gain", "0"]].concat(),
    );
    assert_eq!(meta["method"], "compennet++-res", "{meta}");
    let auto = &meta["training"]["auto"];
    let judged = &auto["judged"];
    let at_stop = judged["settled_at"].as_u64().unwrap() as usize;
    assert!((2..8).contains(&at_stop), "{auto}");
    assert!(judged.get("stopped_at").is_none(), "{auto}");
    let curve = judged["curve"].as_array().unwrap();
    assert_eq!(curve.len(), at_stop + 1, "{auto}");
    let lin = psnr(&auto["candidates"][0]);
    assert!(curve[at_stop - 1..].iter().all(|c| at(c) >= lin), "{auto}");
    assert_eq!(auto["retrained"]["pairs"], 16, "{auto}");
    assert_eq!(meta["training"]["iterations"], 8);
    let alone = dir.path().join("alone");
    res_on(&args, &alone);
    assert!(
        weights(&alone) == weights(&settled),
        "the settled climb's model differs from the rung's"
    );

    // Without structured-light captures, `linear` is the only linear candidate, scored on the
    // held-out pairs the climb is judged on.
    std::fs::remove_dir_all(setup.join("cam/raw/sl")).unwrap();
    let meta = train_auto(&setup, &model, &["--iters", "3"]);
    let auto = &meta["training"]["auto"];
    let methods: Vec<&str> = auto["candidates"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| c["method"].as_str().unwrap())
        .collect();
    assert_eq!(methods, ["linear", "compennet++-res"], "{auto}");
    assert_eq!(auto["held_out"], 4);
    // Without the gray surface capture there is no CompenNet++ rung to climb to, and so
    // nothing to score the lone `linear` against: the record says why.
    std::fs::remove_file(setup.join("cam/raw/ref/img_0126.png")).unwrap();
    let meta = train_auto(&setup, &model, &[]);
    assert_eq!(meta["method"], "linear");
    let auto = &meta["training"]["auto"];
    assert_eq!(auto["candidates"].as_array().unwrap().len(), 0, "{auto}");
    assert!(auto.get("held_out").is_none(), "{auto}");
    let why = auto["why"].as_str().unwrap();
    assert!(why.contains("gray surface"), "{why}");
    assert!(why.contains("`linear` is the only linear rung"), "{why}");
    assert_eq!(meta["training"]["ntrain"], 16);

    // A margin is only for `auto`, and must be a number.
    for (method, gain, says) in [
        ("linear", "0.5", "only `auto` climbs"),
        ("auto", "NaN", "expected a number"),
    ] {
        let out = compend(&[
            "train",
            "--setup",
            setup.to_str().unwrap(),
            "--method",
            method,
            "--climb-gain",
            gain,
        ]);
        assert_code(&out, 2);
        assert!(stderr(&out).contains(says), "{}", stderr(&out));
    }
}

#[test]
fn auto_climbs_only_to_a_rung_whose_live_pass_fits_the_frame_budget() {
    // The climb is timed on this machine's GPU (lavapipe in CI) by the subprocess.
    if crate::common::gpu().is_none() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let setup = make_setup(dir.path(), 16, 2);
    let model = dir.path().join("model");
    let forced = ["--iters", "3", "--climb-gain", "-1000", "--refresh-hz"];
    let live = |meta: &serde_json::Value| meta["training"]["auto"]["live"].clone();
    // A refresh every 1000 s: any pass fits its 500 s budget, and the climb goes on.
    let meta = train_auto(&setup, &model, &[&forced[..], &["0.001"]].concat());
    assert_eq!(meta["method"], "compennet++-res", "{meta}");
    let l = live(&meta);
    assert_eq!(l["method"], "compennet++-res", "{l}");
    assert_eq!(l["refresh_hz"], 0.001, "{l}");
    assert_eq!(l["budget_ms"], 500_000.0, "{l}");
    // The pass wrote the projector frame: the test setup's structured light is NET×NET.
    assert_eq!(l["projector"], serde_json::json!([NET, NET]), "{l}");
    let ms = l["pass_ms"].as_f64().unwrap();
    assert!(ms > 0.0 && ms < 500_000.0, "{l}");
    assert!(l["adapter"].as_str().unwrap().len() > 3, "{l}");
    // A refresh a billion times a second: no pass fits half a nanosecond. The rung is not
    // trained, the best linear rung is, and the record says why.
    let meta = train_auto(&setup, &model, &[&forced[..], &["1e9"]].concat());
    let auto = &meta["training"]["auto"];
    assert!(
        ["linear", "linear-sl"].contains(&meta["method"].as_str().unwrap()),
        "{meta}"
    );
    let methods: Vec<&str> = auto["candidates"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| c["method"].as_str().unwrap())
        .collect();
    assert_eq!(methods, ["linear", "linear-sl"], "{auto}");
    let why = auto["why"].as_str().unwrap();
    assert!(
        why.contains("compennet++-res's live pass takes")
            && why.contains("over the 5.00e-7 ms budget")
            && why.contains("the climb is not trained, the best linear rung is kept"),
        "{why}"
    );
    assert_eq!(live(&meta)["refresh_hz"], 1e9, "{auto}");
    // 0 Hz: not weighed, and any rung may be climbed to.
    let meta = train_auto(&setup, &model, &[&forced[..], &["0"]].concat());
    assert_eq!(meta["method"], "compennet++-res", "{meta}");
    assert!(meta["training"]["auto"].get("live").is_none(), "{meta}");
    // Refused with exit 2 before any work, nothing written, saying `says`.
    let refused = |method: &str, hz: &str, says: &str| {
        let out = dir.path().join("refused");
        let o = compend(&[
            "train",
            "--setup",
            setup.to_str().unwrap(),
            "--method",
            method,
            "--refresh-hz",
            hz,
            "--out",
            out.to_str().unwrap(),
        ]);
        assert_code(&o, 2);
        assert!(stderr(&o).contains(says), "{}", stderr(&o));
        assert!(!out.exists());
    };
    // Only `auto` weighs a climb, at a positive rate.
    for (method, hz, says) in [
        ("linear", "60", "only `auto` weighs a climb's live pass"),
        ("auto", "-60", "expected a refresh rate in Hz, or 0"),
        ("auto", "NaN", "expected a refresh rate in Hz, or 0"),
    ] {
        refused(method, hz, says);
    }
    // A setup that does not record the projector's resolution cannot size the pass, and is
    // named, before anything is fitted.
    std::fs::remove_dir_all(dir.path().join("sl")).unwrap();
    refused("auto", "60", "the projector's resolution is not known");
}

#[test]
fn a_native_lattice_is_the_projectors_resolution() {
    let dir = tempfile::tempdir().unwrap();
    let setup = make_setup(dir.path(), 6, 1);
    let model = dir.path().join("native");
    let run = |out: &Path| {
        compend(&[
            "train",
            "--setup",
            setup.to_str().unwrap(),
            "--method",
            "linear",
            "--lattice",
            "native",
            "--out",
            out.to_str().unwrap(),
        ])
    };
    assert_code(&run(&model), 0);
    let meta = model_json(&model);
    // The test setup's structured light is NET×NET: the projector frame is the canvas.
    assert_eq!(meta["network_size"], serde_json::json!([NET, NET]));
    // Without the patterns that give the projector's size: exit 2, naming what is missing.
    std::fs::remove_dir_all(dir.path().join("sl")).unwrap();
    let o = run(&dir.path().join("native2"));
    assert_code(&o, 2);
    assert!(
        stderr(&o).contains("--lattice native") && stderr(&o).contains("img_0001.png"),
        "{}",
        stderr(&o)
    );
    // The default lattice is then 1.5× the network: the projector's size is not known.
    let default = dir.path().join("default");
    assert_code(&train_linear(&setup, &default), 0);
    let meta = model_json(&default);
    assert_eq!(
        meta["network_size"],
        serde_json::json!([NET * 3 / 2, NET * 3 / 2])
    );
}

#[test]
fn grayscale_and_translucent_captures_are_read_with_a_warning_naming_them() {
    let dir = tempfile::tempdir().unwrap();
    let setup = make_setup(dir.path(), 8, 2);
    let model = dir.path().join("model");
    // Colour captures: no warning.
    let o = train_linear(&setup, &model);
    assert_code(&o, 0);
    assert!(!stderr(&o).contains("WARN"), "{}", stderr(&o));
    // One capture saved as gray, another with transparency: both are read (as RGB), and each
    // is named.
    let s = Setup::open(&setup, None).unwrap();
    let gray = s.capture_path(CaptureSet::Train, 2);
    let rgb = image::open(&gray).unwrap();
    rgb.to_luma8().save(&gray).unwrap();
    let clear = s.capture_path(CaptureSet::Train, 5);
    let mut rgba = image::open(&clear).unwrap().to_rgba8();
    rgba.get_pixel_mut(0, 0).0[3] = 10;
    rgba.save(&clear).unwrap();
    let o = train_linear(&setup, &model);
    assert_code(&o, 0);
    let e = stderr(&o);
    assert!(
        e.contains("1 of 8 captures are grayscale")
            && e.contains(&format!("(the first: {})", gray.display())),
        "{e}"
    );
    assert!(
        e.contains(&format!("{}: alpha channel dropped, 1 of", clear.display())),
        "{e}"
    );
}
