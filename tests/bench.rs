//! `compend bench` end to end at tiny sizes.

use std::path::Path;

use crate::common::{assert_code, compend, stderr};

/// `compend bench` into `out` on the textured plane at tiny sizes, 2 test images, with `extra`
/// flags; it must succeed. Its output and `bench.json`.
fn tiny_bench(out: &Path, extra: &[&str]) -> (std::process::Output, serde_json::Value) {
    let mut args = vec![
        "bench",
        "--out",
        out.to_str().unwrap(),
        "--scenes",
        "textured-plane",
        "--ntest",
        "2",
        "--camera",
        "80x60",
        "--projector",
        "100x75",
        "--network",
        "32",
    ];
    args.extend_from_slice(extra);
    let o = compend(&args);
    assert_code(&o, 0);
    let v = serde_json::from_slice(&std::fs::read(out.join("bench.json")).unwrap()).unwrap();
    (o, v)
}

#[test]
fn bench_writes_rows_for_references_and_methods() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("bench");
    let (_, v) = tiny_bench(&out, &["--methods", "linear", "--ntrain", "6"]);
    let rows = v["rows"].as_array().unwrap();
    let names: Vec<&str> = rows.iter().map(|r| r["method"].as_str().unwrap()).collect();
    assert_eq!(
        names,
        [
            "uncompensated",
            "geometry-only",
            "oracle@network",
            "oracle",
            "linear"
        ]
    );
    let psnr = |k: usize| rows[k]["closed_loop"]["psnr"].as_f64().unwrap();
    // The oracle is the ceiling; the trained model beats projecting the image as is.
    assert!(psnr(3) >= psnr(4) && psnr(3) >= psnr(1), "{v}");
    assert!(psnr(4) > psnr(0), "{v}");
    let lin = &rows[4];
    assert_eq!(lin["ntrain"], 6);
    assert_eq!(lin["captures"], 9);
    assert!(lin["train_seconds"].as_f64().unwrap() > 0.0);
    assert!(lin["paper"]["psnr"].as_f64().unwrap() > 10.0);
    // A working model is not marked as failed.
    assert!(lin["failure"].is_null(), "{lin}");
    let md = std::fs::read_to_string(out.join("bench.md")).unwrap();
    assert!(md.contains("| textured-plane | 0 | linear | 6 |"), "{md}");
    // What no model can fix, per scene and seed, with its picture in the setup.
    let reach = &v["unreachable"][0];
    assert_eq!(reach["scene"], "textured-plane", "{v}");
    let share = reach["unreachable_percent"].as_f64().unwrap();
    assert!((0.0..=100.0).contains(&share), "{reach}");
    assert!(md.contains("| textured-plane | 0 | "), "{md}");
    assert!(md.contains("| scene | seed | unreachable % |"), "{md}");
    assert!(
        out.join("data/seed0-textured-plane/textured-plane/cam/unreachable.png")
            .is_file()
    );
    // Both charts are drawn: real PNGs of the chart size with more than the white background.
    for chart in ["accuracy-vs-training.png", "accuracy-vs-frame.png"] {
        let img = image::open(out.join(chart)).unwrap().to_rgb8();
        assert_eq!(img.dimensions(), (900, 600), "{chart}");
        let inked = img.pixels().filter(|p| p.0 != [255, 255, 255]).count();
        assert!(inked > 2000, "{chart}: only {inked} non-white pixels");
    }

    // A method that does not exist is a usage error.
    let o = compend(&["bench", "--out", out.to_str().unwrap(), "--methods", "nope"]);
    assert_code(&o, 2);
    assert!(stderr(&o).contains("nope"));
    // And so is a climbing margin that is not a number, before anything is written.
    let other = dir.path().join("other");
    for (gain, shown) in [("NaN", "NaN"), ("-inf", "-inf")] {
        let o = compend(&[
            "bench",
            "--out",
            other.to_str().unwrap(),
            "--climb-gain",
            gain,
        ]);
        assert_code(&o, 2);
        assert!(
            stderr(&o).contains(&format!("--climb-gain {shown}: expected a number of dB")),
            "{}",
            stderr(&o)
        );
        assert!(!other.exists());
    }
    // Sizes `sim export` refuses, and a value given twice (the same work twice), before
    // anything is written.
    for (flag, value, says) in [
        (
            "--ntrain",
            "1000000000",
            "--ntrain sizes must be from 4 to 9999",
        ),
        ("--ntrain", "2,48", "--ntrain sizes must be from 4 to 9999"),
        ("--ntest", "100000", "--ntest from 1 to 9999"),
        (
            "--scenes",
            "curved,curved",
            "--scenes (by scene name): curved is given twice",
        ),
        (
            "--methods",
            "linear,linear",
            "--methods: linear is given twice",
        ),
        ("--ntrain", "8,8", "--ntrain: 8 is given twice"),
        ("--seeds", "0,0", "--seeds: 0 is given twice"),
    ] {
        let o = compend(&["bench", "--out", other.to_str().unwrap(), flag, value]);
        assert_code(&o, 2);
        assert!(stderr(&o).contains(says), "{flag} {value}: {}", stderr(&o));
        assert!(!other.exists());
    }
    // And a climbing margin for methods that do not climb.
    let o = compend(&[
        "bench",
        "--out",
        other.to_str().unwrap(),
        "--methods",
        "linear",
        "--climb-gain",
        "1",
    ]);
    assert_code(&o, 2);
    assert!(
        stderr(&o).contains("--climb-gain 1: only the `auto` method climbs"),
        "{}",
        stderr(&o)
    );
    assert!(!other.exists());
    // A training device this build lacks fails before any scene is exported.
    if !cfg!(feature = "cuda") {
        let o = compend(&[
            "bench",
            "--out",
            other.to_str().unwrap(),
            "--methods",
            "auto",
            "--device",
            "cuda",
        ]);
        assert_code(&o, 2);
        assert!(
            stderr(&o).contains("device `cuda:0`: this compend was built without CUDA"),
            "{}",
            stderr(&o)
        );
        assert!(!other.exists());
    }
    // An --out that is a file is refused before any work by every benchmark, the file kept.
    let file = dir.path().join("a-file");
    std::fs::write(&file, "kept").unwrap();
    for cmd in ["bench", "bench-gpu", "bench-train", "bench-serve"] {
        let o = compend(&[cmd, "--out", file.to_str().unwrap()]);
        assert_code(&o, 2);
        assert!(
            stderr(&o).contains("a-file: is a file, not a folder for the results"),
            "{cmd}: {}",
            stderr(&o)
        );
        assert_eq!(std::fs::read_to_string(&file).unwrap(), "kept");
    }
}

/// `--loop-images`: the rungs that take closed-loop pairs train on them as `calibrate` does,
/// the others on the sampling pairs; the pairs keep their desired views.
#[test]
fn bench_takes_closed_loop_pairs_like_calibrate() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("bench");
    let (_, v) = tiny_bench(
        &out,
        &[
            "--methods",
            "linear,compennet++-res,compennet++-cpu,auto",
            "--ntrain",
            "6",
            "--loop-images",
            "4",
            "--iters",
            "2",
            "--batch",
            "2",
        ],
    );
    let rows = v["rows"].as_array().unwrap();
    let row = |m: &str| rows.iter().find(|r| r["method"] == m).unwrap();
    // `auto` takes them as `calibrate` does (here too few sampling pairs to compare on: the
    // linear rung without comparison).
    for m in ["linear", "compennet++-res", "auto"] {
        let r = row(m);
        assert_eq!(r["ntrain"], 6, "{r}");
        assert_eq!(r["loop_pairs"], 4, "{r}");
        assert_eq!(r["captures"], 13, "{r}");
        assert!(r["failed"].is_null(), "{r}");
    }
    assert_eq!(row("auto")["chosen"], "linear");
    let cpu = row("compennet++-cpu");
    assert!(cpu.get("loop_pairs").is_none(), "{cpu}");
    assert_eq!(cpu["captures"], 9, "{cpu}");
    let setup = out.join("data/seed0-textured-plane/textured-plane");
    assert_eq!(
        std::fs::read_dir(setup.join("cam/desire/train"))
            .unwrap()
            .count(),
        4
    );
    assert!(setup.join("cam/raw/train/img_0010.png").is_file());
    let md = std::fs::read_to_string(out.join("bench.md")).unwrap();
    assert!(
        md.contains("| textured-plane | 0 | compennet++-res | 6+4 |"),
        "{md}"
    );
    // The pairs follow one sampling-set size.
    let o = compend(&[
        "bench",
        "--out",
        dir.path().join("two").to_str().unwrap(),
        "--ntrain",
        "6,8",
        "--loop-images",
        "4",
    ]);
    assert_code(&o, 2);
    assert!(
        stderr(&o).contains("--loop-images 4: closed-loop pairs follow the sampling pairs"),
        "{}",
        stderr(&o)
    );
}

#[test]
fn bench_gives_the_spread_across_seeds() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("bench");
    let o = compend(&[
        "bench",
        "--out",
        out.to_str().unwrap(),
        "--scenes",
        "white-plane",
        "--methods",
        "linear",
        "--ntrain",
        "5",
        "--ntest",
        "2",
        "--seeds",
        "3,4",
        "--camera",
        "64x48",
        "--projector",
        "80x60",
        "--network",
        "32",
    ]);
    assert_code(&o, 0);
    let v: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("bench.json")).unwrap()).unwrap();
    let psnr: Vec<f64> = v["rows"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|r| r["method"] == "linear")
        .map(|r| r["closed_loop"]["psnr"].as_f64().unwrap())
        .collect();
    assert_eq!(psnr.len(), 2);
    let mean = (psnr[0] + psnr[1]) / 2.0;
    let (lo, hi) = (psnr[0].min(psnr[1]), psnr[0].max(psnr[1]));
    let md = std::fs::read_to_string(out.join("bench.md")).unwrap();
    let row = format!("| white-plane | linear | 5 | 2 | {mean:.2} ({lo:.2}–{hi:.2}) |");
    assert!(
        md.contains("Across seeds") && md.contains(&row),
        "{row}\n{md}"
    );
    assert_eq!(v["unreachable"].as_array().map(Vec::len), Some(2));
}

#[test]
fn bench_train_measures_the_chosen_rows_in_rounds() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("bt");
    let missing = dir.path().join("no-python");
    let o = compend(&[
        "bench-train",
        "--out",
        out.to_str().unwrap(),
        "--network",
        "16",
        "--camera",
        "64x48",
        "--steps",
        "2",
        "--rounds",
        "2",
        "--frames",
        "1",
        "--methods",
        "linear,compennet++-cpu",
        "--linear-pairs",
        "3",
        "--torch",
        missing.to_str().unwrap(),
    ]);
    assert_code(&o, 0);
    let v: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("bench-train.json")).unwrap()).unwrap();
    assert_eq!(v["rounds"], 2);
    let rows = v["rows"].as_array().unwrap();
    // In the fixed order of the table, whatever the order asked for.
    let names: Vec<&str> = rows.iter().map(|r| r["method"].as_str().unwrap()).collect();
    assert_eq!(names, ["compennet++-cpu", "linear"]);
    let rung = &rows[0];
    assert_eq!(rung["network"], 8);
    assert!(
        rung["train_ms_per_sample"].as_f64().unwrap() > 0.0,
        "{rung}"
    );
    // PyTorch could not run: no ratio, and the row says why, naming the interpreter.
    assert!(rung["candle_over_torch"].is_null(), "{rung}");
    let err = rung["error"].as_str().unwrap();
    assert!(
        err.contains("no-python") && err.contains("could not start"),
        "{err}"
    );
    assert!(rows[1]["train_ms_per_sample"].as_f64().unwrap() > 0.0);

    let o = compend(&[
        "bench-train",
        "--out",
        out.to_str().unwrap(),
        "--methods",
        "compennet",
    ]);
    assert_code(&o, 2);
    assert!(
        stderr(&o).contains("\"compennet\"") && stderr(&o).contains("compennet++-cpu"),
        "{}",
        stderr(&o)
    );
}

#[test]
fn bench_auto_is_checked_on_the_rig_after_a_climb() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("bench");
    // No margin: the residual rung (3 iterations) climbs on the held-out pairs, and the rig
    // projects it and the linear rung fitted beside it on verification images of its own.
    let extra = [
        "--methods",
        "linear,auto",
        "--iters",
        "3",
        "--climb-gain",
        "-1000",
        "--ntrain",
        "12",
    ];
    let (_, v) = tiny_bench(&out, &extra);
    let rows = v["rows"].as_array().unwrap();
    let auto = rows.iter().find(|r| r["method"] == "auto").unwrap();
    let check = auto["rig_check"].as_array().unwrap();
    let methods: Vec<&str> = check
        .iter()
        .map(|c| c["method"].as_str().unwrap())
        .collect();
    assert_eq!(methods.len(), 2, "{auto}");
    assert_eq!(methods[0], "compennet++-res", "{auto}");
    // The best linear rung on the held-out pairs.
    assert!(["linear", "linear-sl"].contains(&methods[1]), "{auto}");
    // Either rung may win on the rig; the row reports the one kept, and a margin of -1000 dB
    // keeps the climbed one whenever it would install.
    let expected = if check[0]["passed"] == true {
        methods[0]
    } else {
        methods[1]
    };
    assert_eq!(auto["chosen"], expected, "{auto}");
    // The linear row had no climb to check.
    let linear = rows.iter().find(|r| r["method"] == "linear").unwrap();
    assert!(linear.get("rig_check").is_none(), "{linear}");
}

#[test]
fn bench_weighs_autos_climb_against_the_frame_budget_when_asked() {
    let dir = tempfile::tempdir().unwrap();
    // Only `auto` weighs a climb: refused with exit 2 before any scene is exported.
    let refused = dir.path().join("refused");
    let o = compend(&[
        "bench",
        "--out",
        refused.to_str().unwrap(),
        "--methods",
        "linear",
        "--refresh-hz",
        "60",
    ]);
    assert_code(&o, 2);
    assert!(
        stderr(&o).contains("add auto to --methods"),
        "{}",
        stderr(&o)
    );
    assert!(!refused.exists());
    // The climb is timed on this machine's GPU (lavapipe in CI).
    if crate::common::gpu().is_none() {
        return;
    }
    // A refresh a billion times a second: no pass fits, so the climb the margin of -1000 dB
    // would take is not trained, and the row says why.
    let out = dir.path().join("bench");
    let extra = [
        "--methods",
        "auto",
        "--iters",
        "3",
        "--climb-gain",
        "-1000",
        "--ntrain",
        "12",
        "--refresh-hz",
        "1e9",
    ];
    let (_, v) = tiny_bench(&out, &extra);
    let rows = v["rows"].as_array().unwrap();
    let auto = rows.iter().find(|r| r["method"] == "auto").unwrap();
    assert!(
        ["linear", "linear-sl"].contains(&auto["chosen"].as_str().unwrap()),
        "{auto}"
    );
    let live = &auto["live"];
    assert_eq!(live["method"], "compennet++-res", "{auto}");
    assert_eq!(live["refresh_hz"], 1e9, "{auto}");
    // The scene's projector frame.
    assert_eq!(live["projector"], serde_json::json!([100, 75]), "{auto}");
    assert!(live["pass_ms"].as_f64().unwrap() > 0.0, "{auto}");
    // No climb, so nothing to check on the rig.
    assert!(auto.get("rig_check").is_none(), "{auto}");
    let md = std::fs::read_to_string(out.join("bench.md")).unwrap();
    assert!(
        md.contains("`auto`'s climb weighed against the display's frame budget")
            && md.contains("compennet++-res's live pass takes")
            && md.contains("over the 5.00e-7 ms budget"),
        "{md}"
    );
}
