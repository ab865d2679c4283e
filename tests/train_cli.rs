//! `compend train`, `eval` and `compensate` refusing bad input through the real binary: every
//! usage or input error exits 2, names the argument or file at fault, and leaves a good model
//! where it was (docs/architecture.md, "Errors and files"). The successful paths are in
//! `tests/train.rs`, whose synthetic setup these tests use.

use std::path::Path;

use compend::raster::Rgb;

use crate::common::{assert_code, compend, stderr, stdout};
use crate::train::make_setup;

/// The bytes of the good model's weights, to check that a failed command left them alone.
fn weights(model: &Path) -> Vec<u8> {
    std::fs::read(model.join("model.safetensors")).unwrap()
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
    let before = weights(&model);

    bad_train_arguments(s, m);
    assert_eq!(weights(&model), before);
    bad_photometric_init(dir.path(), s, m);
    assert_eq!(weights(&model), before);

    bad_training_captures(&setup, m);
    assert_eq!(weights(&model), before);

    // A missing reference capture names the file.
    let white = setup.join("cam/raw/ref/img_0125.png");
    std::fs::remove_file(&white).unwrap();
    let out = compend(&["train", "--setup", s, "--method", "linear", "--out", m]);
    assert_code(&out, 2);
    assert!(stderr(&out).contains("img_0125.png"), "{}", stderr(&out));
    assert_eq!(weights(&model), before);

    bad_model_files(dir.path(), &model, s);
    bad_compensate_inputs(dir.path(), m);
}

/// Training captures that show no projector light, and closed-loop desired views that are not
/// the training set's last pairs, each with its view: exit 2 naming the folder or the file.
/// The setup is left as it was.
fn bad_training_captures(setup: &Path, m: &str) {
    let s = setup.to_str().unwrap();
    let train = setup.join("cam/raw/train");
    let names: Vec<_> = (1..=8).map(compend::pngio::indexed_name).collect();
    let kept: Vec<Vec<u8>> = names
        .iter()
        .map(|n| std::fs::read(train.join(n)).unwrap())
        .collect();
    // Every capture as dark as the black reference: the projector was off.
    for n in &names {
        std::fs::copy(setup.join("cam/raw/ref/img_0001.png"), train.join(n)).unwrap();
    }
    let out = compend(&["train", "--setup", s, "--method", "linear", "--out", m]);
    assert_code(&out, 2);
    let e = stderr(&out);
    assert!(
        e.contains("cam/raw/train")
            && e.contains("none of the 8 training captures shows projector light"),
        "{e}"
    );
    for (n, bytes) in names.iter().zip(&kept) {
        std::fs::write(train.join(n), bytes).unwrap();
    }

    // Desired views for pairs 6 and 8 of 8: the view of pair 7 is missing.
    let views = setup.join("cam/desire/train");
    std::fs::create_dir_all(&views).unwrap();
    for i in [6, 8] {
        let n = compend::pngio::indexed_name(i);
        std::fs::copy(train.join(&n), views.join(&n)).unwrap();
    }
    for method in ["linear", "auto"] {
        let out = compend(&["train", "--setup", s, "--method", method, "--out", m]);
        assert_code(&out, 2);
        let e = stderr(&out);
        assert!(
            e.contains("cam/desire/train/img_0007.png: missing") && e.contains("closed-loop"),
            "{method}: {e}"
        );
    }
    // `inspect` says the same.
    let out = compend(&["inspect", "--setup", s]);
    assert_code(&out, 2);
    assert!(
        stdout(&out).contains("img_0007.png") || stderr(&out).contains("img_0007.png"),
        "{}{}",
        stdout(&out),
        stderr(&out)
    );
    // The view of pair 7 there, but at the projector images' size: `inspect` names it too.
    let n = compend::pngio::indexed_name(7);
    // The setup is ROOT/lab/pos1.
    let root = setup.ancestors().nth(2).unwrap();
    std::fs::copy(root.join("train").join(&n), views.join(&n)).unwrap();
    let out = compend(&["inspect", "--setup", s]);
    assert_code(&out, 2);
    let said = format!("{}{}", stdout(&out), stderr(&out));
    assert!(said.contains("cam/desire/train/img_0007.png"), "{said}");
    std::fs::remove_dir_all(&views).unwrap();
}

/// More training pairs than exist, an unknown method, a lattice too small or for a method that
/// has none: exit 2 naming what is wrong.
fn bad_train_arguments(s: &str, m: &str) {
    // More training pairs than exist: names the folder and the counts.
    let out = compend(&[
        "train", "--setup", s, "--method", "linear", "--ntrain", "50", "--out", m,
    ]);
    assert_code(&out, 2);
    assert!(
        stderr(&out).contains("cam/raw/train") && stderr(&out).contains("50"),
        "{}",
        stderr(&out)
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
}

/// A missing or mismatched photometric pre-initialisation names the file.
fn bad_photometric_init(dir: &Path, s: &str, m: &str) {
    let weights = dir.join("w4.safetensors");
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
        let path = dir.join(file);
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
}

/// A corrupt model file, an old format version, a missing model: exit 2 naming the file.
fn bad_model_files(dir: &Path, model: &Path, s: &str) {
    let bad = dir.join("bad-model");
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

    // Weights that are not the ones model.json was saved with (here one value altered; a
    // file from another model of the same shapes alike) are refused, naming both files.
    let mut weights = std::fs::read(model.join("model.safetensors")).unwrap();
    let last = weights.len() - 1;
    weights[last] ^= 0x01;
    std::fs::write(bad.join("model.safetensors"), &weights).unwrap();
    let out = compend(&["eval", "--model", bad.to_str().unwrap(), "--setup", s]);
    assert_code(&out, 2);
    assert!(
        stderr(&out).contains("model.safetensors: not the weights")
            && stderr(&out).contains("model.json"),
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
        dir.join("nope").to_str().unwrap(),
        "--input",
        s,
        "--out",
        s,
    ]);
    assert_code(&out, 2);
}

/// A desired image of the wrong size names the file and both sizes (camera pixels).
fn bad_compensate_inputs(dir: &Path, m: &str) {
    let wrong = dir.join("wrong.png");
    compend::pngio::write_rgb(&wrong, &Rgb::<compend::raster::Camera>::new(10, 10)).unwrap();
    let out = compend(&[
        "compensate",
        "--model",
        m,
        "--input",
        wrong.to_str().unwrap(),
        "--out",
        dir.join("o").to_str().unwrap(),
    ]);
    assert_code(&out, 2);
    assert!(
        stderr(&out).contains("wrong.png") && stderr(&out).contains("48x40"),
        "{}",
        stderr(&out)
    );
    // A folder of inputs where an image's name leads nowhere (a broken link) or to a folder:
    // named, not skipped; `metrics` on that folder says the same.
    for odd in ["link", "folder"] {
        let inputs = dir.join(format!("inputs-{odd}"));
        std::fs::create_dir_all(&inputs).unwrap();
        let bad = inputs.join("img_0002.png");
        match odd {
            "link" => std::os::unix::fs::symlink(dir.join("nowhere.png"), &bad).unwrap(),
            _ => std::fs::create_dir(&bad).unwrap(),
        }
        let out = compend(&[
            "compensate",
            "--model",
            m,
            "--input",
            inputs.to_str().unwrap(),
            "--out",
            dir.join(format!("o-{odd}")).to_str().unwrap(),
        ]);
        assert_code(&out, 2);
        assert!(
            stderr(&out).contains("img_0002.png: not a regular file"),
            "{}",
            stderr(&out)
        );
        assert!(!dir.join(format!("o-{odd}")).exists());
        let i = inputs.to_str().unwrap();
        let out = compend(&["metrics", i, i]);
        assert_code(&out, 2);
        assert!(
            stderr(&out).contains("img_0002.png: not a regular file"),
            "{}",
            stderr(&out)
        );
    }
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
