//! Nothing of the user's is destroyed: `train --out` replaces only a model directory, checks the
//! path before any work, and a save killed at any moment leaves the previous model loadable and
//! no temporary file behind after the next run. Suspect inputs are named in warnings or errors.

use std::collections::BTreeMap;
use std::fs;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Duration;

use compend::model::Model;
use compend::raster::{ImageSize, Rgb};

use crate::common::{assert_code, compend, stderr, train_linear};
use crate::train::make_setup;

/// Every file under `dir` (relative path → bytes).
fn snapshot(dir: &Path) -> BTreeMap<PathBuf, Vec<u8>> {
    let mut out = BTreeMap::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else {
                out.insert(
                    p.strip_prefix(dir).unwrap().to_path_buf(),
                    fs::read(&p).unwrap(),
                );
            }
        }
    }
    out
}

#[test]
fn train_out_refuses_anything_but_a_model_directory_before_any_work() {
    let dir = tempfile::tempdir().unwrap();
    let setup = make_setup(dir.path(), 6, 1);

    // A folder of notes, the setup itself, a regular file, a symbolic link: exit 2, untouched.
    let notes = dir.path().join("notes");
    fs::create_dir(&notes).unwrap();
    fs::write(notes.join("todo.txt"), b"calibrate on Monday").unwrap();
    let file = dir.path().join("model-file");
    fs::write(&file, b"precious").unwrap();
    let link = dir.path().join("link");
    std::os::unix::fs::symlink(&notes, &link).unwrap();
    let before_setup = snapshot(&setup);
    for (out, says) in [
        (&notes, "todo.txt"),
        (&setup, "not a model directory"),
        (&file, "is a file"),
        (&link, "symbolic link"),
    ] {
        let o = train_linear(&setup, out);
        assert_code(&o, 2);
        let err = stderr(&o);
        assert!(
            err.contains(says) && err.contains(out.to_str().unwrap()),
            "{err}"
        );
        // Refused before the fit: no progress of a fit, no model written anywhere.
        assert!(!err.contains("trained"), "{err}");
    }
    assert_eq!(snapshot(&setup), before_setup);
    assert_eq!(
        fs::read(notes.join("todo.txt")).unwrap(),
        b"calibrate on Monday"
    );
    assert_eq!(fs::read(&file).unwrap(), b"precious");
    assert!(
        fs::symlink_metadata(&link)
            .unwrap()
            .file_type()
            .is_symlink()
    );
    // No temporary sibling of any of them.
    for e in fs::read_dir(dir.path()).unwrap() {
        let name = e.unwrap().file_name().to_string_lossy().into_owned();
        assert!(!name.contains(".tmp-") && !name.contains(".old-"), "{name}");
    }

    // An output folder that cannot be created: exit 2 before the fit.
    let o = train_linear(&setup, &file.join("sub/model"));
    assert_code(&o, 2);
    assert!(stderr(&o).contains("model-file"), "{}", stderr(&o));

    // A model directory and an empty folder may be replaced.
    let model = dir.path().join("model");
    assert_code(&train_linear(&setup, &model), 0);
    assert_code(&train_linear(&setup, &model), 0);
    let empty = dir.path().join("empty");
    fs::create_dir(&empty).unwrap();
    assert_code(&train_linear(&setup, &empty), 0);
    Model::load(&empty).unwrap();

    // A model's metadata beside a folder named like its weights, holding someone's work: not a
    // model directory, so nothing in it is removed.
    let like = dir.path().join("like-a-model");
    fs::create_dir_all(like.join("model.safetensors")).unwrap();
    fs::copy(model.join("model.json"), like.join("model.json")).unwrap();
    fs::write(like.join("model.safetensors/thesis.txt"), b"chapter 1").unwrap();
    let o = train_linear(&setup, &like);
    assert_code(&o, 2);
    assert!(stderr(&o).contains("not a plain file"), "{}", stderr(&o));
    assert_eq!(
        fs::read(like.join("model.safetensors/thesis.txt")).unwrap(),
        b"chapter 1"
    );
}

#[test]
fn a_killed_save_leaves_the_previous_model_and_the_next_run_cleans_up() {
    let dir = tempfile::tempdir().unwrap();
    let setup = make_setup(dir.path(), 6, 1);
    let model = dir.path().join("model");
    assert_code(&train_linear(&setup, &model), 0);
    let good = snapshot(&model);

    // What a save killed half-way leaves: a temporary sibling of a process that is gone.
    let dead = dir.path().join(".model.tmp-999999999");
    fs::create_dir(&dead).unwrap();
    fs::write(dead.join("model.safetensors"), vec![0u8; 1 << 20]).unwrap();
    let dead_old = dir.path().join(".model.old-999999998");
    fs::create_dir(&dead_old).unwrap();

    // Kill runs at staggered moments: whatever the moment, the path holds a loadable model.
    for delay_ms in [30, 90, 200, 400, 700, 1000] {
        let mut child = Command::new(env!("CARGO_BIN_EXE_compend"))
            .args([
                "train",
                "--setup",
                setup.to_str().unwrap(),
                "--method",
                "linear",
                "--seed",
                &delay_ms.to_string(),
                "--out",
                model.to_str().unwrap(),
            ])
            .stderr(std::process::Stdio::null())
            .spawn()
            .unwrap();
        std::thread::sleep(Duration::from_millis(delay_ms));
        let _ = child.kill();
        child.wait().unwrap();
        Model::load(&model).unwrap_or_else(|e| panic!("killed after {delay_ms} ms: {e}"));
    }
    // The next complete run removes every leftover, its own and the dead processes'.
    assert_code(&train_linear(&setup, &model), 0);
    let left: Vec<String> = fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with(".model."))
        .collect();
    assert!(left.is_empty(), "{left:?}");
    // The final model is a complete one, of the same shape as the first.
    let now = snapshot(&model);
    assert_eq!(
        now.keys().collect::<Vec<_>>(),
        good.keys().collect::<Vec<_>>()
    );
}

#[test]
fn suspect_inputs_are_named_not_silently_accepted() {
    let dir = tempfile::tempdir().unwrap();
    let setup = make_setup(dir.path(), 6, 1);
    let s = setup.to_str().unwrap();
    let m = dir.path().join("m");

    // --iters 0 and --batch 0 are refused, and so is --iters for a closed-form rung.
    for (method, flag, value, says) in [
        ("compennet++-cpu", "--iters", "0", "--iters 0"),
        ("compennet++-cpu", "--batch", "0", "--batch 0"),
        ("linear", "--iters", "5", "closed-form"),
    ] {
        let o = compend(&[
            "train",
            "--setup",
            s,
            "--method",
            method,
            flag,
            value,
            "--out",
            m.to_str().unwrap(),
        ]);
        assert_code(&o, 2);
        assert!(stderr(&o).contains(says), "{}", stderr(&o));
    }

    // A translucent RGBA capture is read without its alpha, with a warning naming it.
    let cap = setup.join("cam/raw/train/img_0002.png");
    let rgb = compend::pngio::read_rgb::<compend::raster::Camera>(&cap).unwrap();
    let ImageSize {
        width: w,
        height: h,
    } = rgb.size();
    let mut rgba = image::RgbaImage::new(w as u32, h as u32);
    for (x, y, p) in rgba.enumerate_pixels_mut() {
        let c = rgb.get(x as usize, y as usize);
        let q = |v: f32| (v * 255.0).round() as u8;
        *p = image::Rgba([q(c[0]), q(c[1]), q(c[2]), if x == 0 { 128 } else { 255 }]);
    }
    rgba.save(&cap).unwrap();
    // A missing gray surface capture: the linear rungs train, with a warning.
    fs::remove_file(setup.join("cam/raw/ref/img_0126.png")).unwrap();
    let o = train_linear(&setup, &m);
    assert_code(&o, 0);
    let err = stderr(&o);
    assert!(
        err.contains("img_0002.png") && err.contains("alpha"),
        "{err}"
    );
    assert!(
        err.contains("img_0126.png") && err.contains("missing"),
        "{err}"
    );

    // `metrics B A` with more PNGs in B than in A names the unpaired file.
    let a = dir.path().join("a");
    let b = dir.path().join("b");
    for (folder, names) in [(&a, &["x.png"][..]), (&b, &["x.png", "y.png"][..])] {
        for n in names {
            compend::pngio::write_rgb(&folder.join(n), &Rgb::<compend::raster::Camera>::new(4, 4))
                .unwrap();
        }
    }
    for (first, second) in [(&a, &b), (&b, &a)] {
        let o = compend(&["metrics", first.to_str().unwrap(), second.to_str().unwrap()]);
        assert_code(&o, 2);
        assert!(stderr(&o).contains("y.png"), "{}", stderr(&o));
    }
}

#[test]
fn a_wrong_size_size_setter_is_blamed_not_the_good_images() {
    let dir = tempfile::tempdir().unwrap();
    let setup = make_setup(dir.path(), 6, 1);
    // The black reference sets the camera size; make it the odd one out.
    let black = setup.join("cam/raw/ref/img_0001.png");
    compend::pngio::write_rgb(&black, &Rgb::<compend::raster::Camera>::new(10, 10)).unwrap();
    let o = train_linear(&setup, &dir.path().join("m"));
    assert_code(&o, 2);
    let err = stderr(&o);
    assert!(err.contains("img_0001.png: image is 10x10"), "{err}");
    let o = compend(&["inspect", "--setup", setup.to_str().unwrap()]);
    assert_code(&o, 2);
    let err = stderr(&o);
    assert!(
        err.contains(&format!("{}: image is 10x10", black.display())),
        "{err}"
    );
}
