//! `compend play` on the virtual rig: raw frames on standard input, patterns and images through
//! the GPU pass, with frame counts checked; usage errors exit with 2.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

use crate::common::{assert_code, compend, gpu, stderr};

/// A tiny simulated setup and a `linear` model trained on it (absolute paths, so the model finds
/// its setup's rig.json from any folder).
pub fn tiny_model(dir: &Path) -> PathBuf {
    tiny_model_with(dir, &["--method", "linear"])
}

/// [`tiny_model`] trained with `train_args` (the method and its settings).
pub fn tiny_model_with(dir: &Path, train_args: &[&str]) -> PathBuf {
    let root = dir.join("root");
    let o = compend(&[
        "sim",
        "export",
        "--scene",
        "textured-plane",
        "--out",
        root.to_str().unwrap(),
        "--ntrain",
        "6",
        "--ntest",
        "1",
        "--camera",
        "80x60",
        "--projector",
        "100x75",
        "--network",
        "32",
        "--no-cube",
    ]);
    assert_code(&o, 0);
    let model = dir.join("model");
    let setup = root.join("textured-plane");
    let mut args = vec![
        "train",
        "--setup",
        setup.to_str().unwrap(),
        "--out",
        model.to_str().unwrap(),
    ];
    args.extend_from_slice(train_args);
    let o = compend(&args);
    assert_code(&o, 0);
    model
}

/// `n` raw rgb24 frames of `w`×`h`, each a different ramp.
pub fn raw_frames(n: usize, w: usize, h: usize) -> Vec<u8> {
    let mut out = Vec::with_capacity(n * w * h * 3);
    for f in 0..n {
        for _y in 0..h {
            for x in 0..w {
                let v = ((x * 6 + f * 40) % 256) as u8;
                out.extend_from_slice(&[v, 255 - v, (f * 50 % 256) as u8]);
            }
        }
    }
    out
}

/// Runs `compend play ...` with `stdin` piped in; returns (output, parsed JSON when exit 0).
pub fn play_with_stdin(
    args: &[&str],
    stdin: &[u8],
) -> (std::process::Output, Option<serde_json::Value>) {
    let mut child = Command::new(env!("CARGO_BIN_EXE_compend"))
        .arg("play")
        .args(args)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("compend runs");
    let mut pipe = child.stdin.take().unwrap();
    let data = stdin.to_vec();
    // Write from a thread: the player may stop reading early on an error.
    let writer = std::thread::spawn(move || {
        let _ = pipe.write_all(&data);
    });
    let out = child.wait_with_output().unwrap();
    writer.join().unwrap();
    let json = (out.status.code() == Some(0))
        .then(|| serde_json::from_str(String::from_utf8_lossy(&out.stdout).trim()).unwrap());
    (out, json)
}

pub fn count(v: &serde_json::Value, k: &str) -> u64 {
    v[k].as_u64().unwrap_or_else(|| panic!("{k} in {v}"))
}

#[test]
fn raw_pipe_plays_through_the_virtual_rig() {
    if gpu().is_none() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let model = tiny_model(dir.path());
    let m = model.to_str().unwrap();
    let frames = raw_frames(5, 40, 30);
    let src = "raw:-?size=40x30&format=rgb24";

    // Offline pacing: every frame shown exactly once, one camera view each.
    let out = dir.path().join("views");
    let (o, v) = play_with_stdin(
        &[
            "--model",
            m,
            "--source",
            src,
            "--rig",
            "virtual",
            "--pace",
            "source",
            "--out",
            out.to_str().unwrap(),
            "--json",
        ],
        &frames,
    );
    assert_code(&o, 0);
    let v = v.unwrap();
    eprintln!("{v}");
    assert_eq!(count(&v, "received"), 5);
    assert_eq!(count(&v, "shown"), 5);
    assert_eq!(count(&v, "dropped_source"), 0);
    assert_eq!(count(&v, "dropped_pipeline"), 0);
    assert_eq!(count(&v, "camera_views"), 5);
    for i in 1..=5 {
        let p = out.join(format!("cam_{i:06}.png"));
        assert_eq!(
            compend::pngio::png_size(&p).unwrap(),
            (80, 60),
            "{}",
            p.display()
        );
    }
    let saved: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("play.json")).unwrap()).unwrap();
    assert_eq!(saved["shown"], 5);
    // Different frames look different to the camera.
    let a =
        compend::pngio::read_rgb::<compend::raster::Camera>(&out.join("cam_000001.png")).unwrap();
    let b =
        compend::pngio::read_rgb::<compend::raster::Camera>(&out.join("cam_000003.png")).unwrap();
    assert!(compend::metrics::score_pairs([(&a, &b)]).unwrap().psnr < 40.0);

    // Live pacing at 60 Hz: the pipe is faster than the display, so frames are dropped at the
    // source, but every frame is accounted for and the last one is shown.
    let out = dir.path().join("live");
    let (o, v) = play_with_stdin(
        &[
            "--model",
            m,
            "--source",
            src,
            "--rig",
            "virtual",
            "--out",
            out.to_str().unwrap(),
            "--json",
        ],
        &frames,
    );
    assert_code(&o, 0);
    let v = v.unwrap();
    eprintln!("{v}");
    assert_eq!(count(&v, "received"), 5);
    assert!(count(&v, "shown") >= 1);
    assert_eq!(count(&v, "shown") + count(&v, "dropped_source"), 5);
    assert!(
        out.join("cam_000005.png").is_file(),
        "the last frame is shown"
    );

    // A stream that ends inside a frame: the size or format is wrong.
    let (o, _) = play_with_stdin(
        &[
            "--model",
            m,
            "--source",
            "raw:-?size=40x31&format=rgb24",
            "--rig",
            "virtual",
            "--pace",
            "source",
        ],
        &frames,
    );
    assert_code(&o, 2);
    assert!(stderr(&o).contains("check ?size="), "{}", stderr(&o));
}

#[test]
fn patterns_images_and_usage_errors() {
    if gpu().is_none() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let model = tiny_model(dir.path());
    let m = model.to_str().unwrap();
    let o = compend(&[
        "play",
        "--model",
        m,
        "--source",
        "pattern:moving?size=64x36&fps=240&frames=4",
        "--rig",
        "virtual:textured-plane",
        "--pace",
        "source",
        "--json",
    ]);
    assert_code(&o, 0);
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(count(&v, "shown"), 4);

    // A still image: shown once, then the virtual rig stops (nothing more would change).
    let img = dir.path().join("still.png");
    compend::pngio::write_rgb(
        &img,
        &compend::raster::Rgb::<compend::raster::Unspecified>::filled(24, 16, [0.8, 0.5, 0.2]),
    )
    .unwrap();
    let o = compend(&[
        "play",
        "--model",
        m,
        "--source",
        img.to_str().unwrap(),
        "--rig",
        "virtual",
        "--json",
    ]);
    assert_code(&o, 0);
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(count(&v, "shown"), 1);

    for (args, what) in [
        (
            vec![
                "--model",
                m,
                "--source",
                "raw:-?size=12",
                "--rig",
                "virtual",
            ],
            "size",
        ),
        (
            vec!["--model", m, "--source", "pattern:nope", "--rig", "virtual"],
            "nope",
        ),
        (
            vec![
                "--model",
                m,
                "--source",
                "/no/such/file.png",
                "--rig",
                "virtual",
            ],
            "/no/such",
        ),
        (
            vec![
                "--model",
                "/no/such/model",
                "--source",
                "pattern:bars",
                "--rig",
                "virtual",
            ],
            "/no/such/model",
        ),
        (
            vec!["--model", m, "--source", "pattern:bars", "--rig", "real"],
            "virtual",
        ),
        (
            vec![
                "--model",
                m,
                "--source",
                "pattern:bars",
                "--rig",
                "virtual:no-such-scene",
            ],
            "no-such-scene",
        ),
    ] {
        let mut full = vec!["play"];
        full.extend(args);
        let o = compend(&full);
        assert_code(&o, 2);
        assert!(stderr(&o).contains(what), "{full:?}: {}", stderr(&o));
    }
    // The spellings are documented in --help.
    let o = compend(&["play", "--help"]);
    let help = crate::common::stdout(&o);
    for s in [
        "raw:-?size=WxH",
        "v4l2:",
        "pattern:NAME",
        "folder:DIR",
        "--rig",
    ] {
        assert!(help.contains(s), "--help lacks {s}");
    }
}
