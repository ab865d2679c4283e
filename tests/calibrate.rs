//! `compend calibrate` on the virtual rig through the real binary: a verified model is
//! installed and its record written; an interrupted calibration resumes from the captures on
//! disk; a rig whose camera does not see the projector, captures of another pattern set, a
//! camera that is not there and a bad output path are refused with exit 2, the installed model
//! untouched.

use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use crate::common::{assert_code, compend, latency_trials, stderr, stdout};

/// Tiny sizes: a run takes seconds in the test profile.
const TINY: [&str; 6] = [
    "--rig-camera",
    "160x120",
    "--projector",
    "200x150",
    "--network",
    "64",
];

pub(crate) fn calibrate_args<'a>(data: &'a str, extra: &[&'a str]) -> Vec<&'a str> {
    let ntrain = if extra.contains(&"--ntrain") {
        &[][..]
    } else {
        &["--ntrain", "12"][..]
    };
    let mut a = vec!["calibrate", "--data", data];
    a.extend_from_slice(ntrain);
    a.extend_from_slice(&["--ntest", "4", "--verify", "3", "--json"]);
    a.extend_from_slice(&TINY);
    a.extend_from_slice(extra);
    a
}

fn record(out: &std::process::Output) -> serde_json::Value {
    serde_json::from_str(stdout(out).trim()).unwrap_or_else(|e| panic!("{e}: {}", stdout(out)))
}

#[test]
fn calibrate_installs_a_verified_model_and_records_it() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("cal");
    let d = data.to_str().unwrap();
    let o = compend(&calibrate_args(
        d,
        &["--rig", "virtual:textured-plane", "--seed", "4"],
    ));
    assert_code(&o, 0);
    let r = record(&o);
    let v = &r["verification"];
    assert_eq!(v["passed"], true, "{r}");
    assert!(v["gain_db"].as_f64().unwrap() > 3.0, "{r}");
    assert!(v.get("failure").is_none(), "{r}");
    // What no model can fix is reported: a textured plane in full view has little of it, and
    // every reason's share adds up to the whole.
    let u = &r["unreachable"];
    let pc = |k: &str| u[k].as_f64().unwrap();
    assert!(pc("unreachable_percent") < 10.0, "{u}");
    let parts = [
        "shadowed_percent",
        "saturated_percent",
        "too_dark_percent",
        "too_bright_percent",
    ];
    let sum: f64 = parts.iter().map(|k| pc(k)).sum();
    assert!((sum - pc("unreachable_percent")).abs() < 1e-9, "{u}");
    let picture = data.join("capture/cam/unreachable.png");
    assert_eq!(
        compend::pngio::png_size(&picture).unwrap(),
        compend::raster::ImageSize::new(160, 120)
    );
    // The scene's camera delay is 2 frames: the measurement finds it (a frame more when a
    // show comes late on the wall clock), and captures wait that long and no more unless
    // retakes ask for it.
    let trials = latency_trials(&r);
    assert!(trials.iter().all(|&t| (2..=3).contains(&t)), "{r}");
    let worst = *trials.iter().max().unwrap();
    let settle = r["latency"]["settle_frames"].as_u64().unwrap();
    let retakes = r["retakes"].as_u64().unwrap();
    assert!(settle >= worst && settle <= worst + retakes, "{r}");
    // The captures against their floor: on the wall clock the virtual camera gives 30 frames
    // a second and no more, so the captures cannot beat (latency + averaged frames) / rate.
    let f = &r["capture_floor"];
    let fps = f["fps"].as_f64().unwrap();
    assert!((fps - 30.0).abs() < 0.5, "{f}");
    let floor = f["frames"].as_f64().unwrap() / fps;
    assert!(f["seconds"].as_f64().unwrap() >= 0.95 * floor, "{f}");
    // Every capture (white flashes between closed-loop pairs included) waits the worst measured
    // latency and averages 3 frames.
    let captures = f["captures"].as_u64().unwrap();
    assert!(captures >= 3 + 12 + 4 + 12, "{f}");
    assert!(
        f["frames"].as_u64().unwrap() <= captures * (worst + 3),
        "{f}"
    );
    // Black, white, gray, the sampling and test images, and as many closed-loop pairs as
    // sampling pairs (the default for a linear rung).
    assert_eq!(r["captured"], 3 + 12 + 4 + 12);
    assert_eq!(r["loop_pairs"], 12, "{r}");
    // The test images as they are were captured by this run: the verification scores those
    // captures as the uncompensated projection instead of projecting them again.
    assert_eq!(v["uncompensated_from_test_pairs"], true, "{r}");
    // The virtual camera has a manual exposure: ranging put the brightest lit pixels just below
    // saturation.
    let bright = r["exposure"]["bright_level"].as_f64().unwrap();
    assert!((0.88..0.97).contains(&bright), "{r}");
    let err = stderr(&o);
    assert!(
        err.contains("installed linear")
            && err.contains("verification")
            && err.contains("of the displayable area cannot be compensated")
            && err.contains("against a floor of"),
        "{err}"
    );
    // Without a terminal, progress comes as lines: one as each phase starts, with n of N.
    for phase in [
        "calibrate: latency 0/1",
        "calibrate: captures 0/19",
        "calibrate: closed-loop pairs 0/12",
    ] {
        assert!(err.contains(phase), "no {phase:?} in {err}");
    }
    // The installed model carries the record, loads and evaluates on the captured test pairs.
    let model = data.join("model");
    let meta: serde_json::Value =
        serde_json::from_slice(&std::fs::read(model.join("model.json")).unwrap()).unwrap();
    assert_eq!(meta["calibration"]["verification"], *v);
    // Playback maps content into the range the calibration measured.
    let range = &meta["calibration"]["display_range"];
    assert!(
        range["low"].as_f64().unwrap() < range["high"].as_f64().unwrap(),
        "{range}"
    );
    // The calibration folder is a complete setup in the dataset layout; inspect takes the
    // projector's aspect from the calibration's record, finds the displayable area the
    // calibration placed the desired views in, reports the same share of it out of reach and
    // draws where.
    let shown = dir.path().join("inspect");
    let o = compend(&[
        "inspect",
        "--setup",
        data.join("capture").to_str().unwrap(),
        "--out",
        shown.to_str().unwrap(),
        "--json",
    ]);
    assert_code(&o, 0);
    let report: serde_json::Value = serde_json::from_str(stdout(&o).trim()).unwrap();
    assert_eq!(
        report["projector"],
        serde_json::json!({"width": 200, "height": 150}),
        "{report}"
    );
    assert_eq!(report["projector_from"], "recorded by the calibration");
    assert_eq!(report["fov"]["unreachable"], *u, "{report}");
    let view = compend::pngio::read_rgb::<compend::raster::Camera>(
        &data.join("capture/cam/desire/test/img_0001.png"),
    )
    .unwrap();
    let lit: Vec<(usize, usize)> = (0..view.height())
        .flat_map(|y| (0..view.width()).map(move |x| (x, y)))
        .filter(|&(x, y)| view.get(x, y).iter().any(|&v| v > 0.0))
        .collect();
    // The views continue the content's edge EDGE_MARGIN_PX camera pixels past the area.
    let area = &report["fov"]["displayable_area"];
    let at = |k: &str| area[k].as_u64().unwrap() as usize;
    let m = compend::fov::EDGE_MARGIN_PX;
    let span = |f: fn(&(usize, usize)) -> usize| {
        (
            lit.iter().map(f).min().unwrap(),
            lit.iter().map(f).max().unwrap(),
        )
    };
    assert_eq!(
        span(|p| p.0),
        (at("x") - m, at("x") + at("width") - 1 + m),
        "{area}"
    );
    assert_eq!(
        span(|p| p.1),
        (at("y") - m, at("y") + at("height") - 1 + m),
        "{area}"
    );
    let text = stdout(&compend(&[
        "inspect",
        "--setup",
        data.join("capture").to_str().unwrap(),
    ]));
    assert!(
        text.contains("projector     200x150 (recorded by the calibration)"),
        "{text}"
    );
    assert!(shown.join("unreachable.png").is_file());
    assert_code(
        &compend(&[
            "eval",
            "--model",
            model.to_str().unwrap(),
            "--setup",
            data.join("capture").to_str().unwrap(),
        ]),
        0,
    );
}

#[test]
fn auto_climbs_only_when_the_rig_confirms_it_in_closed_loop() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("cal");
    let d = data.to_str().unwrap();
    let meta = |o: &std::process::Output| -> serde_json::Value {
        assert_code(o, 0);
        serde_json::from_slice(&std::fs::read(data.join("model/model.json")).unwrap()).unwrap()
    };
    // No margin: the residual rung (3 iterations) is trained on every pair, its correction on
    // the 12 closed-loop pairs taken with `linear`, with no held-out judgement; the rig
    // projects both it and the linear rung fitted beside it on the verification images.
    let rig = [
        "--rig",
        "virtual:textured-plane",
        "--seed",
        "4",
        "--method",
        "auto",
    ];
    let forced = [&rig[..], &["--climb-iters", "3", "--climb-gain", "-1000"]].concat();
    let o = compend(&calibrate_args(d, &forced));
    // A margin below zero is allowed, and said to let a lower-scoring rung through.
    assert!(
        stderr(&o).contains("--climb-gain -1000: a negative margin keeps a climbed rung"),
        "{}",
        stderr(&o)
    );
    let m = meta(&o);
    let auto = &m["training"]["auto"];
    let scores = auto["closed_loop"].as_array().unwrap();
    let methods: Vec<&str> = scores
        .iter()
        .map(|c| c["method"].as_str().unwrap())
        .collect();
    assert_eq!(methods, ["compennet++-res", "linear"], "{auto}");
    assert_eq!(m["method"], "compennet++-res", "{auto}");
    assert_eq!(auto["chosen"], m["method"]);
    assert_eq!(m["training"]["iterations"], 3);
    // The record's verification is the kept rung's, and both rungs were scored on the rig.
    let v = &m["calibration"]["verification"];
    assert_eq!(v["psnr"], scores[0]["psnr"], "{m}");
    assert!(
        scores
            .iter()
            .all(|c| c["psnr"].as_f64().unwrap() > v["uncompensated_psnr"].as_f64().unwrap())
    );
    let rule = auto["rule"].as_str().unwrap();
    assert!(
        rule.contains("the rig judges the climb") && rule.contains("kept on the rig only if"),
        "{auto}"
    );
    for says in ["auto: closed loop on the rig", "for the rig to judge"] {
        assert!(stderr(&o).contains(says), "{says}: {}", stderr(&o));
    }
    // `linear` alone (the rig takes no structured light) is not scored on sampling pairs, and
    // the record says why; nothing was judged on held-out pairs.
    assert!(auto.get("held_out").is_none(), "{auto}");
    assert!(auto.get("fitted_on").is_none(), "{auto}");
    assert_eq!(auto["candidates"].as_array().unwrap().len(), 0, "{auto}");
    assert!(
        auto["why"]
            .as_str()
            .unwrap()
            .contains("`linear` is the only linear rung"),
        "{auto}"
    );
    assert!(auto.get("loop_held_out").is_none(), "{auto}");
    assert!(auto.get("judged").is_none(), "{auto}");
    // The rung was trained once, on every pair, its correction on all 12 closed-loop pairs:
    // the rung `train` makes alone on the same setup, to the bit.
    assert_eq!(m["calibration"]["loop_pairs"], 12, "{m}");
    assert_eq!(m["training"]["ntrain"], 24, "{m}");
    assert_eq!(auto["retrained"]["pairs"], 24, "{m}");
    assert!(
        m["training"]["correction"]
            .as_str()
            .unwrap()
            .starts_with("12 closed-loop pairs"),
        "{m}"
    );
    let alone = dir.path().join("alone");
    assert_code(
        &compend(&[
            "train",
            "--setup",
            data.join("capture").to_str().unwrap(),
            "--method",
            "compennet++-res",
            "--iters",
            "3",
            "--out",
            alone.to_str().unwrap(),
        ]),
        0,
    );
    assert!(
        std::fs::read(alone.join("model.safetensors")).unwrap()
            == std::fs::read(data.join("model/model.safetensors")).unwrap(),
        "the climbed rung is the rung trained alone"
    );

    // `train --method auto` on the same setup, which has no rig, judges on the closed-loop
    // pairs held out of its training.
    let train_auto = |out: &Path| {
        compend(&[
            "train",
            "--setup",
            data.join("capture").to_str().unwrap(),
            "--method",
            "auto",
            "--iters",
            "3",
            "--out",
            out.to_str().unwrap(),
        ])
    };
    let offline = dir.path().join("offline");
    assert_code(&train_auto(&offline), 0);
    let m: serde_json::Value =
        serde_json::from_slice(&std::fs::read(offline.join("model.json")).unwrap()).unwrap();
    let held = &m["training"]["auto"]["loop_held_out"];
    assert_eq!(held["pairs"], 4, "{m}");
    assert_eq!(held["trained_on"], 8, "{m}");
    assert_eq!(m["training"]["auto"]["required_gain_db"], 0.5, "{m}");
    // A damaged held-out desired view: exit 2 naming it, and no model.
    let view = data.join("capture/cam/desire/train/img_0024.png");
    std::fs::write(&view, b"not a png").unwrap();
    let damaged = dir.path().join("damaged");
    let o = train_auto(&damaged);
    assert_code(&o, 2);
    assert!(
        stderr(&o).contains("desire/train/img_0024.png"),
        "{}",
        stderr(&o)
    );
    assert!(!damaged.exists());

    // With fewer than 8 closed-loop pairs the climb is trained on the sampling pairs before
    // the closed-loop pairs are taken; the linear rung the climbed one is compared with takes
    // them.
    let few = dir.path().join("few");
    let o = compend(&calibrate_args(
        few.to_str().unwrap(),
        &[&forced[..], &["--loop-images", "5"]].concat(),
    ));
    assert_code(&o, 0);
    let m: serde_json::Value =
        serde_json::from_slice(&std::fs::read(few.join("model/model.json")).unwrap()).unwrap();
    assert_eq!(m["method"], "compennet++-res", "{m}");
    assert!(m["training"]["auto"].get("loop_held_out").is_none(), "{m}");
    assert!(m["training"]["auto"].get("judged").is_none(), "{m}");
    assert_eq!(m["calibration"]["loop_pairs"], 5, "{m}");
    assert_eq!(m["training"]["auto"]["retrained"]["pairs"], 12, "{m}");
    assert_eq!(m["training"]["ntrain"], 12, "{m}");
    // `train --method auto` on that setup, whose 5 closed-loop pairs now follow the 12: judged
    // on the sampling pairs, the rung is trained again on those 12 alone, as it was judged
    // (paper protocol), not with its correction on the 5 closed-loop pairs.
    let again = dir.path().join("again");
    let o = compend(&[
        "train",
        "--setup",
        few.join("capture").to_str().unwrap(),
        "--method",
        "auto",
        "--iters",
        "3",
        "--climb-gain",
        "-1000",
        "--out",
        again.to_str().unwrap(),
    ]);
    assert_code(&o, 0);
    let m: serde_json::Value =
        serde_json::from_slice(&std::fs::read(again.join("model.json")).unwrap()).unwrap();
    assert_eq!(m["method"], "compennet++-res", "{m}");
    assert_eq!(m["training"]["auto"]["judged"]["iterations"], 3, "{m}");
    assert_eq!(m["training"]["auto"]["retrained"]["pairs"], 12, "{m}");
    assert_eq!(m["training"]["ntrain"], 12, "{m}");
    assert_eq!(
        m["training"]["correction"],
        "12 pairs, paper protocol (input a capture, target its projector image)",
        "{m}"
    );

    // The default margin (0.2 dB on the rig) on 3 iterations: the rung, hardly moved from the
    // `linear` it starts at, is projected beside the linear rung and turned down; the linear
    // rung fitted on every pair is installed, the rig's figures recorded.
    let o = compend(&calibrate_args(
        d,
        &[&rig[..], &["--climb-iters", "3"]].concat(),
    ));
    let m = meta(&o);
    assert_eq!(m["method"], "linear", "{m}");
    let auto = &m["training"]["auto"];
    assert_eq!(auto["chosen"], "linear", "{m}");
    assert_eq!(auto["required_gain_db"], 0.2, "{m}");
    let scores = auto["closed_loop"].as_array().unwrap();
    let psnr = |k: usize| scores[k]["psnr"].as_f64().unwrap();
    assert_eq!(scores[0]["method"], "compennet++-res", "{m}");
    assert!(psnr(0) - psnr(1) < 0.2, "{m}");
    assert_eq!(
        m["calibration"]["verification"]["psnr"], scores[1]["psnr"],
        "{m}"
    );
    assert_eq!(m["calibration"]["loop_pairs"], 12, "{m}");
    assert_eq!(m["training"]["ntrain"], 24, "{m}");

    // The climbing flags are for `auto` only, and must be numbers.
    for (flags, says) in [
        (&["--climb-gain", "0.5"][..], "only `--method auto` climbs"),
        (
            &["--method", "auto", "--climb-gain", "NaN"][..],
            "expected a number",
        ),
        (
            &["--method", "auto", "--climb-iters", "0"][..],
            "at least 1",
        ),
        (
            &["--refresh-hz", "60"][..],
            "only `auto` weighs a climb's live pass; linear is one rung",
        ),
        (
            &["--method", "auto", "--refresh-hz", "-1"][..],
            "expected a refresh rate in Hz",
        ),
    ] {
        let o = compend(&calibrate_args(
            d,
            &[&["--rig", "virtual"][..], flags].concat(),
        ));
        assert_code(&o, 2);
        assert!(stderr(&o).contains(says), "{}", stderr(&o));
    }
}

#[test]
fn auto_weighs_its_climbs_live_pass_when_asked() {
    // The virtual rig's projector plays through no GPU: `--refresh-hz` times the climb on this
    // machine's (lavapipe in CI).
    if crate::common::gpu().is_none() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("cal");
    let extra = [
        "--rig",
        "virtual:textured-plane",
        "--seed",
        "4",
        "--method",
        "auto",
        "--loop-images",
        "0",
        "--climb-iters",
        "3",
        "--climb-gain",
        "-1000",
        "--refresh-hz",
        "1e9",
    ];
    let o = compend(&calibrate_args(data.to_str().unwrap(), &extra));
    assert_code(&o, 0);
    assert!(
        stderr(&o).contains("auto climbs only to a rung whose live pass on"),
        "{}",
        stderr(&o)
    );
    let m: serde_json::Value =
        serde_json::from_slice(&std::fs::read(data.join("model/model.json")).unwrap()).unwrap();
    // Even a margin that keeps any rung does not climb to one the display cannot play.
    assert_eq!(m["method"], "linear", "{m}");
    let auto = &m["training"]["auto"];
    let live = &auto["live"];
    assert_eq!(live["method"], "compennet++-res", "{m}");
    assert_eq!(live["projector"], serde_json::json!([200, 150]), "{m}");
    assert!(live["pass_ms"].as_f64().unwrap() > 0.0, "{m}");
    assert!(
        auto["why"]
            .as_str()
            .unwrap()
            .contains("the climb is not trained"),
        "{m}"
    );
    assert!(auto.get("closed_loop").is_none(), "{m}");
}

#[test]
fn closed_loop_pairs_refit_the_linear_rung_on_every_pair() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("cal");
    let d = data.to_str().unwrap();
    let rig = ["--rig", "virtual:textured-plane", "--seed", "4"];
    let o = compend(&calibrate_args(
        d,
        &[&rig[..], &["--loop-images", "5"]].concat(),
    ));
    assert_code(&o, 0);
    let r = record(&o);
    assert_eq!(r["loop_pairs"], 5, "{r}");
    assert_eq!(r["verification"]["passed"], true, "{r}");
    // 12 sampling pairs and 5 closed-loop ones, in the dataset layout, all fitted on.
    let count = |p: &Path| std::fs::read_dir(p).unwrap().count();
    assert_eq!(count(&data.join("train")), 17);
    assert_eq!(count(&data.join("capture/cam/raw/train")), 17);
    let m: serde_json::Value =
        serde_json::from_slice(&std::fs::read(data.join("model/model.json")).unwrap()).unwrap();
    assert_eq!(m["training"]["ntrain"], 17, "{m}");
    assert_eq!(m["calibration"]["loop_pairs"], 5, "{m}");
    // The fit on every pair grew while the closed-loop pairs were captured: its response
    // curves are those of the first fit, searched on the 12 sampling pairs (the geometry's
    // pairs, all of them here), which `train` on those pairs finds again.
    assert_eq!(m["training"]["curves_searched_on"], 12, "{m}");
    let first = dir.path().join("first");
    let o = compend(&[
        "train",
        "--setup",
        data.join("capture").to_str().unwrap(),
        "--method",
        "linear",
        "--ntrain",
        "12",
        "--out",
        first.to_str().unwrap(),
    ]);
    assert_code(&o, 0);
    let f: serde_json::Value =
        serde_json::from_slice(&std::fs::read(first.join("model.json")).unwrap()).unwrap();
    assert_eq!(f["training"]["curves"], m["training"]["curves"], "{f}");
    assert_eq!(f["training"]["curves_searched_on"], 12, "{f}");
    // A closed-loop image is the compensation of a sampling image, not the image itself: it
    // lies within the projector's range and differs from its content.
    let first = image::open(data.join("train/img_0001.png"))
        .unwrap()
        .to_rgb8();
    let looped = image::open(data.join("train/img_0013.png"))
        .unwrap()
        .to_rgb8();
    assert_eq!(first.dimensions(), looped.dimensions());
    let differ = first
        .pixels()
        .zip(looped.pixels())
        .filter(|(a, b)| a != b)
        .count();
    assert!(differ > first.len() / 6, "{differ}");
    // Each closed-loop pair keeps the desired view it was compensated for, under its index.
    assert_eq!(count(&data.join("capture/cam/desire/train")), 5);
    assert!(data.join("capture/cam/desire/train/img_0013.png").is_file());
    residual_correction_trains_on_the_closed_loop_pairs(dir.path(), &data);

    // On a dark surface the display range is a few hundredths wide and two closed-loop images
    // in a row look alike to the camera: the synchronisation still sees each one arrive.
    let dark = dir.path().join("dark");
    let o = compend(&calibrate_args(
        dark.to_str().unwrap(),
        &["--rig", "virtual:dark-texture", "--seed", "77"],
    ));
    assert_code(&o, 0);
    assert_eq!(record(&o)["loop_pairs"], 12);

    let o = compend(&calibrate_args(
        d,
        &[&rig[..], &["--loop-images", "501"]].concat(),
    ));
    assert_code(&o, 2);
    assert!(
        stderr(&o).contains("--loop-images 501: at most 500"),
        "{}",
        stderr(&o)
    );
    // A data root with a training image after the sampling ones that compend did not write:
    // the closed-loop pair that would replace it is refused, and the image is left as it was.
    let theirs = dir.path().join("theirs");
    std::fs::create_dir_all(theirs.join("train")).unwrap();
    let their_image = theirs.join("train/img_0013.png");
    std::fs::copy(data.join("train/img_0013.png"), &their_image).unwrap();
    let bytes = std::fs::read(&their_image).unwrap();
    let o = compend(&calibrate_args(theirs.to_str().unwrap(), &rig));
    assert_code(&o, 2);
    assert!(
        stderr(&o).contains("img_0013.png: a training image this calibration did not write"),
        "{}",
        stderr(&o)
    );
    assert_eq!(std::fs::read(&their_image).unwrap(), bytes);
    // The calibration's own closed-loop images are replaced when it runs again.
    let o = compend(&calibrate_args(
        d,
        &[&rig[..], &["--loop-images", "5"]].concat(),
    ));
    assert_code(&o, 0);
    // Only the rungs that take closed-loop pairs get them, whether asked by flag or by the configuration.
    let o = compend(&calibrate_args(
        d,
        &[
            &rig[..],
            &["--method", "compennet++-cpu", "--loop-images", "3"],
        ]
        .concat(),
    ));
    assert_code(&o, 2);
    assert!(
        stderr(&o).contains("--loop-images 3: only linear, linear-sl, compennet++-res, compennet++-res-full and auto"),
        "{}",
        stderr(&o)
    );
    let config = dir.path().join("c.toml");
    std::fs::write(&config, "[calibration]\nloop_images = 3\n").unwrap();
    let o = compend(&calibrate_args(
        d,
        &[
            &rig[..],
            &[
                "--config",
                config.to_str().unwrap(),
                "--method",
                "compennet++-cpu",
            ],
        ]
        .concat(),
    ));
    assert_code(&o, 2);
    assert!(
        stderr(&o).contains(
            "the configuration's loop_images = 3: only linear, linear-sl, compennet++-res, compennet++-res-full and auto"
        ),
        "{}",
        stderr(&o)
    );
}

/// `compennet++-res` on a calibration's data root: with its closed-loop pairs among the
/// training pairs its correction trains on them (and says so in the record), without them on
/// the sampling pairs; a damaged desired view is refused naming the file.
fn residual_correction_trains_on_the_closed_loop_pairs(dir: &Path, data: &Path) {
    let setup = data.join("capture");
    let o = compend(&["inspect", "--setup", setup.to_str().unwrap()]);
    assert_code(&o, 0);
    assert!(
        stdout(&o).contains("closed loop   5 pairs (train 13–17"),
        "{}",
        stdout(&o)
    );
    let train = |ntrain: Option<&str>, out: &Path| {
        let mut args = vec![
            "train",
            "--setup",
            setup.to_str().unwrap(),
            "--method",
            "compennet++-res",
            "--iters",
            "2",
            "--batch",
            "2",
            "--out",
            out.to_str().unwrap(),
        ];
        if let Some(n) = ntrain {
            args.extend(["--ntrain", n]);
        }
        compend(&args)
    };
    let model = |out: &Path| -> serde_json::Value {
        serde_json::from_slice(&std::fs::read(out.join("model.json")).unwrap()).unwrap()
    };
    let correction = |out: &Path| {
        model(out)["training"]["correction"]
            .as_str()
            .unwrap()
            .to_string()
    };
    // By default every pair up to the last closed-loop one.
    let looped = dir.join("res-loop");
    assert_code(&train(None, &looped), 0);
    assert_eq!(model(&looped)["training"]["ntrain"], 17);
    // Its `linear` is on the projector's lattice, as the calibration's was: the data root has
    // no structured light, and the calibration's manifest says the projector's size.
    assert_eq!(
        model(&looped)["network_size"],
        model(&data.join("model"))["network_size"]
    );
    assert!(
        correction(&looped).starts_with("5 closed-loop pairs"),
        "{}",
        correction(&looped)
    );
    let sampled = dir.join("res-sampling");
    assert_code(&train(Some("12"), &sampled), 0);
    assert!(
        correction(&sampled).starts_with("12 pairs, paper protocol"),
        "{}",
        correction(&sampled)
    );
    // A damaged desired view: exit 2 naming it, the copy of the data root otherwise intact.
    let copy = dir.join("damaged");
    copy_dir(data, &copy);
    let bad = copy.join("capture/cam/desire/train/img_0014.png");
    std::fs::write(&bad, b"not a png").unwrap();
    let o = compend(&[
        "train",
        "--setup",
        copy.join("capture").to_str().unwrap(),
        "--method",
        "compennet++-res",
        "--ntrain",
        "17",
        "--iters",
        "2",
        "--out",
        dir.join("res-bad").to_str().unwrap(),
    ]);
    assert_code(&o, 2);
    assert!(
        stderr(&o).contains("desire/train/img_0014.png"),
        "{}",
        stderr(&o)
    );
    assert!(!dir.join("res-bad").exists());
    // The first closed-loop view lost (or the whole folder of views): the manifest's 12
    // sampling pairs say pair 13 is a closed-loop pair, so it is refused naming the view, not
    // taken as a sampling pair. A fit of the sampling pairs alone does not use it.
    std::fs::write(
        &bad,
        std::fs::read(data.join("capture/cam/desire/train/img_0014.png")).unwrap(),
    )
    .unwrap();
    let views = copy.join("capture/cam/desire/train");
    let copied_setup = copy.join("capture");
    let lost_view = |method: &str, ntrain: Option<&str>| {
        let out = dir.join("lost-view");
        let mut args = vec![
            "train",
            "--setup",
            copied_setup.to_str().unwrap(),
            "--method",
            method,
            "--out",
            out.to_str().unwrap(),
        ];
        if let Some(n) = ntrain {
            args.extend(["--ntrain", n]);
        }
        compend(&args)
    };
    std::fs::remove_file(views.join("img_0013.png")).unwrap();
    for folder_too in [false, true] {
        if folder_too {
            std::fs::remove_dir_all(&views).unwrap();
        }
        for method in ["linear", "auto"] {
            let o = lost_view(method, None);
            assert_code(&o, 2);
            assert!(
                stderr(&o).contains("desire/train/img_0013.png")
                    && stderr(&o).contains("records 12 sampling pairs"),
                "{method}: {}",
                stderr(&o)
            );
        }
        let o = compend(&["inspect", "--setup", copy.join("capture").to_str().unwrap()]);
        assert_code(&o, 2);
        assert!(
            stderr(&o).contains("desire/train/img_0013.png"),
            "{}",
            stderr(&o)
        );
    }
    assert!(!dir.join("lost-view").exists());
    assert_code(&lost_view("linear", Some("12")), 0);
    // A view on a sampling pair is named as such.
    copy_dir(&data.join("capture/cam/desire/train"), &views);
    std::fs::copy(views.join("img_0013.png"), views.join("img_0012.png")).unwrap();
    let o = lost_view("linear", None);
    assert_code(&o, 2);
    assert!(
        stderr(&o)
            .contains("desire/train/img_0012.png: a desired view for training pair 12, which")
            && stderr(&o).contains("records as a sampling pair"),
        "{}",
        stderr(&o)
    );
}

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for entry in std::fs::read_dir(from).unwrap() {
        let entry = entry.unwrap();
        let target = to.join(entry.file_name());
        if entry.file_type().unwrap().is_dir() {
            copy_dir(&entry.path(), &target);
        } else {
            std::fs::copy(entry.path(), &target).unwrap();
        }
    }
}

/// `calibrate --method compennet++-res`: `linear` takes the closed-loop pairs and the rung's
/// correction trains on them; `--iters` is for the CompenNet++ rungs only.
#[test]
fn calibrate_trains_the_residual_correction_on_closed_loop_pairs() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("cal");
    let d = data.to_str().unwrap();
    let rig = ["--rig", "virtual:curved", "--seed", "8"];
    let o = compend(&calibrate_args(
        d,
        &[
            &rig[..],
            &[
                "--method",
                "compennet++-res",
                "--iters",
                "3",
                "--loop-images",
                "4",
            ],
        ]
        .concat(),
    ));
    assert_code(&o, 0);
    let r = record(&o);
    assert_eq!(r["loop_pairs"], 4, "{r}");
    assert_eq!(r["verification"]["passed"], true, "{r}");
    let m: serde_json::Value =
        serde_json::from_slice(&std::fs::read(data.join("model/model.json")).unwrap()).unwrap();
    assert_eq!(m["method"], "compennet++-res", "{m}");
    assert_eq!(m["training"]["ntrain"], 16, "{m}");
    assert_eq!(m["training"]["iterations"], 3, "{m}");
    let correction = m["training"]["correction"].as_str().unwrap();
    assert!(
        correction.starts_with("4 closed-loop pairs"),
        "{correction}"
    );
    let files = std::fs::read_dir(data.join("capture/cam/desire/train")).unwrap();
    assert_eq!(files.count(), 4);
    for (method, why) in [("linear", "closed-form fit"), ("auto", "use --climb-iters")] {
        let o = compend(&calibrate_args(
            d,
            &[&rig[..], &["--method", method, "--iters", "3"]].concat(),
        ));
        assert_code(&o, 2);
        assert!(
            stderr(&o).contains(&format!(
                "--iters 3: only the CompenNet++ rungs train in iterations, not {method}"
            )) && stderr(&o).contains(why),
            "{}",
            stderr(&o)
        );
    }
    let o = compend(&calibrate_args(
        d,
        &[&rig[..], &["--method", "compennet++-res", "--iters", "0"]].concat(),
    ));
    assert_code(&o, 2);
    assert!(
        stderr(&o).contains("--iters 0: expected at least 1"),
        "{}",
        stderr(&o)
    );
}

#[test]
fn an_interrupted_calibration_resumes_without_recapturing() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("cal");
    let d = data.to_str().unwrap();
    let args = calibrate_args(d, &["--rig", "virtual:curved", "--ntrain", "40"]);
    // Kill it once the manifest lists a few captures.
    let mut child = Command::new(env!("CARGO_BIN_EXE_compend"))
        .args(&args)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let manifest = data.join("capture/calibration.json");
    let start = Instant::now();
    let listed = |m: &Path| -> usize {
        std::fs::read(m)
            .ok()
            .and_then(|b| serde_json::from_slice::<serde_json::Value>(&b).ok())
            .map_or(0, |v| v["captured"].as_array().map_or(0, |a| a.len()))
    };
    while listed(&manifest) < 6 {
        assert!(
            child.try_wait().unwrap().is_none(),
            "finished before the kill"
        );
        assert!(start.elapsed() < Duration::from_secs(120), "no captures");
        std::thread::sleep(Duration::from_millis(2));
    }
    child.kill().unwrap();
    child.wait().unwrap();
    let before = listed(&manifest);
    let first = data.join("capture/cam/raw/ref/img_0001.png");
    let black = std::fs::read(&first).unwrap();

    let o = compend(&args);
    assert_code(&o, 0);
    let r = record(&o);
    let resumed = r["resumed"].as_u64().unwrap() as usize;
    assert!(resumed >= before, "{resumed} resumed, {before} listed: {r}");
    assert_eq!(
        resumed + r["captured"].as_u64().unwrap() as usize,
        3 + 40 + 4 + 40
    );
    // The kill came before the closed-loop pairs: all 40 taken now.
    assert!(r["captured"].as_u64().unwrap() >= 40, "{r}");
    // What was on disk was not captured again.
    assert_eq!(std::fs::read(&first).unwrap(), black);
    assert_eq!(r["verification"]["passed"], true, "{r}");

    // Killed between a closed-loop pair's desired view and its capture: the view of pair 80
    // is there, its capture is not. That pair was not taken yet, and the next run resumes.
    let last = data.join("capture/cam/raw/train/img_0080.png");
    assert!(data.join("capture/cam/desire/train/img_0080.png").is_file());
    std::fs::remove_file(&last).unwrap();
    let o = compend(&args);
    assert_code(&o, 0);
    assert!(last.is_file(), "the pair was taken again");
    // The other closed-loop pairs are of the images the same model compensates again: kept.
    let r = record(&o);
    assert_eq!(
        (r["resumed"].as_u64(), r["captured"].as_u64()),
        (Some(3 + 40 + 4 + 39), Some(1)),
        "{r}"
    );
}

#[test]
fn bad_rigs_and_paths_exit_2_and_keep_the_installed_model() {
    // No rig at all: every way to name one is offered.
    let o = compend(&["calibrate"]);
    assert_code(&o, 2);
    for way in ["--rig", "--camera", "--config"] {
        assert!(stderr(&o).contains(way), "{}", stderr(&o));
    }
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("cal");
    let d = data.to_str().unwrap();
    assert_code(&compend(&calibrate_args(d, &["--rig", "virtual"])), 0);
    let model = data.join("model");
    let installed = std::fs::read(model.join("model.safetensors")).unwrap();

    // A projector turned away from the surface: the camera sees no change.
    let scene = stdout(&compend(&["sim", "show", "curved"]));
    let mut s: serde_json::Value = serde_json::from_str(&scene).unwrap();
    s["projector"]["pose"]["rotation_deg"] = serde_json::json!([0.0, 120.0, 0.0]);
    let away = dir.path().join("away.json");
    std::fs::write(&away, s.to_string()).unwrap();
    let rig = format!("virtual:{}", away.display());
    let other = dir.path().join("other");
    let o = compend(&calibrate_args(
        other.to_str().unwrap(),
        &["--rig", &rig, "--out", model.to_str().unwrap()],
    ));
    assert_code(&o, 2);
    assert!(
        stderr(&o).contains("does not see the projector"),
        "{}",
        stderr(&o)
    );

    // Captures of another pattern set (another seed) in the same folder.
    let o = compend(&calibrate_args(d, &["--rig", "virtual", "--seed", "9"]));
    assert_code(&o, 2);
    assert!(stderr(&o).contains("another pattern set"), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("this calibration projects seed 9, 12 training"),
        "{}",
        stderr(&o)
    );
    // Its patterns without its captures (the setup set aside): another seed is refused too,
    // naming the first pattern that differs, and so is an image of someone else's in place of
    // one of this set's; the patterns stay as they were.
    let aside = dir.path().join("capture-aside");
    std::fs::rename(data.join("capture"), &aside).unwrap();
    let first = data.join("train/img_0001.png");
    let pattern = std::fs::read(&first).unwrap();
    let o = compend(&calibrate_args(d, &["--rig", "virtual", "--seed", "9"]));
    assert_code(&o, 2);
    let e = stderr(&o);
    assert!(e.contains(first.to_str().unwrap()), "{e}");
    assert!(
        e.contains("another image, not the image to be written"),
        "{e}"
    );
    assert!(e.contains("sampling seed 9"), "{e}");
    assert!(e.contains("choose another data folder (--data"), "{e}");
    assert_eq!(std::fs::read(&first).unwrap(), pattern);
    let theirs = data.join("test/img_0002.png");
    let kept = std::fs::read(&theirs).unwrap();
    std::fs::copy(data.join("ref/img_0125.png"), &theirs).unwrap();
    let o = compend(&calibrate_args(d, &["--rig", "virtual"]));
    assert_code(&o, 2);
    let e = stderr(&o);
    assert!(e.contains(theirs.to_str().unwrap()), "{e}");
    assert_eq!(
        std::fs::read(&theirs).unwrap(),
        std::fs::read(data.join("ref/img_0125.png")).unwrap()
    );
    std::fs::write(&theirs, kept).unwrap();
    if data.join("capture").exists() {
        std::fs::remove_dir_all(data.join("capture")).unwrap();
    }
    std::fs::rename(&aside, data.join("capture")).unwrap();

    // An output path holding something else, and a rig that is not one.
    let notes = dir.path().join("notes.txt");
    std::fs::write(&notes, b"keep").unwrap();
    let o = compend(&calibrate_args(
        d,
        &["--rig", "virtual", "--out", notes.to_str().unwrap()],
    ));
    assert_code(&o, 2);
    assert_eq!(std::fs::read(&notes).unwrap(), b"keep");
    let o = compend(&calibrate_args(d, &["--rig", "usb"]));
    assert_code(&o, 2);
    assert!(stderr(&o).contains("virtual:SCENE"), "{}", stderr(&o));

    // A training device this build lacks, for a method that trains: refused before anything is
    // projected or written.
    if !cfg!(feature = "cuda") {
        let fresh = dir.path().join("fresh");
        let o = compend(&calibrate_args(
            fresh.to_str().unwrap(),
            &["--rig", "virtual", "--method", "auto", "--device", "cuda"],
        ));
        assert_code(&o, 2);
        assert!(
            stderr(&o).contains("device `cuda:0`: this compend was built without CUDA"),
            "{}",
            stderr(&o)
        );
        assert!(!fresh.exists());
    }

    // Hardware: no such camera, a file that is not one, and the two kinds of rig together.
    for (camera, says) in [
        ("/dev/video-none-here", "video-none-here"),
        ("/etc/hostname", "/etc/hostname"),
    ] {
        let o = compend(&[
            "calibrate",
            "--camera",
            camera,
            "--data",
            d,
            "--out",
            model.to_str().unwrap(),
        ]);
        assert_code(&o, 2);
        assert!(stderr(&o).contains(says), "{}", stderr(&o));
    }
    // Refused before any capture, in a folder of its own: the default data folder it made (and
    // locked) goes again, and nothing is left behind.
    let cwd = tempfile::tempdir().unwrap();
    let o = crate::common::compend_in(
        cwd.path(),
        &[
            "calibrate",
            "--camera",
            "/dev/null",
            "--out",
            "elsewhere/model",
        ],
    );
    assert_code(&o, 2);
    assert!(stderr(&o).contains("/dev/null"), "{}", stderr(&o));
    let left: Vec<_> = std::fs::read_dir(cwd.path()).unwrap().collect();
    assert!(left.is_empty(), "left behind: {left:?}");
    let o = compend(&["calibrate", "--camera", "/dev/video0", "--rig", "virtual"]);
    assert_code(&o, 2);
    let o = compend(&["calibrate", "--data", d]);
    assert_code(&o, 2);

    assert_eq!(
        std::fs::read(model.join("model.safetensors")).unwrap(),
        installed
    );
}

/// `--ntrain auto` on the tiny rig: the sampling pairs are taken in rounds (16, then 8 more)
/// until one no longer gains, the closed-loop pairs follow the count chosen unless the first 8
/// show that more would not pay, and both choices are recorded with why; a white plane takes
/// fewer captures than a dark texture. A rerun resumes every capture. A method the rounds
/// cannot score, or a count that is not one, exits 2.
#[test]
fn ntrain_auto_takes_sampling_pairs_in_rounds_until_one_no_longer_gains() {
    let dir = tempfile::tempdir().unwrap();
    let mut chosen = Vec::new();
    for (scene, seed) in [("white-plane", "8"), ("dark-texture", "9")] {
        let data = dir.path().join(scene);
        let d = data.to_str().unwrap();
        let rig = format!("virtual:{scene}");
        let args = calibrate_args(d, &["--rig", &rig, "--seed", seed, "--ntrain", "auto"]);
        let o = compend(&args);
        assert_code(&o, 0);
        let r = record(&o);
        let s = &r["sampling"];
        let rounds: Vec<u64> = s["rounds"]
            .as_array()
            .unwrap_or_else(|| panic!("no rounds: {r}"))
            .iter()
            .map(|x| x["pairs"].as_u64().unwrap())
            .collect();
        let n = s["chosen"].as_u64().unwrap();
        // 16 first, 8 more each round, the last round's count kept.
        assert_eq!(rounds[0], 16, "{s}");
        assert!(rounds.windows(2).all(|w| w[1] == w[0] + 8), "{s}");
        assert_eq!(rounds.last(), Some(&n), "{s}");
        assert!(n <= 48, "{s}");
        let why = s["why"].as_str().unwrap();
        assert!(
            why.contains("less than the") || (n == 48 && why.contains("the most")),
            "{s}"
        );
        assert!(
            stderr(&o).contains("calibrate: sampling rounds"),
            "{}",
            stderr(&o)
        );
        // The closed-loop pairs: the first 8, then as many as the sampling pairs or no more,
        // with the figures that decided; everything is on disk and in the manifest.
        let c = &r["closed_loop"];
        let loops = c["chosen"]
            .as_u64()
            .unwrap_or_else(|| panic!("no choice: {r}"));
        assert_eq!(r["loop_pairs"].as_u64(), Some(loops), "{r}");
        assert_eq!(c["judged"].as_u64(), Some(8), "{c}");
        let (share, why) = (c["share"].as_f64().unwrap(), c["why"].as_str().unwrap());
        let (model_mse, closed) = (
            c["model_mse"].as_f64().unwrap(),
            c["closed_loop_mse"].as_f64().unwrap(),
        );
        assert!(model_mse > 0.0 && closed > 0.0, "{c}");
        assert!((share - model_mse / closed).abs() < 1e-9, "{c}");
        if share < 0.15 {
            assert!(loops == 8 && why.contains("less than the 15 %"), "{c}");
        } else {
            assert!(loops == n && why.contains("not less than"), "{c}");
        }
        assert!(
            stderr(&o).contains(&format!("calibrate: closed-loop pairs: {loops} taken")),
            "{}",
            stderr(&o)
        );
        let pairs = n + loops;
        assert_eq!(r["captured"].as_u64(), Some(3 + 4 + pairs), "{r}");
        assert_eq!(r["resumed"].as_u64(), Some(0), "{r}");
        let manifest: serde_json::Value =
            serde_json::from_slice(&std::fs::read(data.join("capture/calibration.json")).unwrap())
                .unwrap();
        assert_eq!(manifest["patterns"]["ntrain"].as_u64(), Some(n));
        let listed = |p: &Path| std::fs::read_dir(p).unwrap().count() as u64;
        assert_eq!(listed(&data.join("train")), pairs);
        assert_eq!(listed(&data.join("capture/cam/raw/train")), pairs);
        assert_eq!(r["verification"]["passed"], true, "{r}");
        let model: serde_json::Value =
            serde_json::from_slice(&std::fs::read(data.join("model/model.json")).unwrap()).unwrap();
        assert_eq!(model["calibration"]["sampling"], *s);
        assert_eq!(model["calibration"]["closed_loop"], *c);
        assert_eq!(model["training"]["ntrain"].as_u64(), Some(pairs));
        chosen.push((n, loops, r["captured"].as_u64().unwrap()));
        // A rerun finds every capture on disk (the counts were settled by the closed-loop
        // pairs) and judges the closed-loop pairs as the first run did.
        if scene == "white-plane" {
            let o = compend(&args);
            assert_code(&o, 0);
            let again = record(&o);
            assert_eq!(again["captured"].as_u64(), Some(0), "{again}");
            assert_eq!(again["resumed"].as_u64(), Some(3 + 4 + pairs), "{again}");
            // Captures found on disk may be of other light: the test images are projected
            // again, 3 of them beside the 3 compensated ones (the only captures of this run),
            // and score close to the first run's captures of them.
            let (v0, v1) = (&r["verification"], &again["verification"]);
            assert_eq!(v0["uncompensated_from_test_pairs"], true, "{r}");
            assert_eq!(v1["uncompensated_from_test_pairs"], false, "{again}");
            assert_eq!(
                again["capture_floor"]["captures"].as_u64(),
                Some(6),
                "{again}"
            );
            let (u0, u1) = (
                v0["uncompensated_psnr"].as_f64().unwrap(),
                v1["uncompensated_psnr"].as_f64().unwrap(),
            );
            assert!(
                (u0 - u1).abs() < 0.3,
                "{u0} dB from the test pairs, {u1} projected again"
            );
            assert_eq!(again["loop_pairs"].as_u64(), Some(loops), "{again}");
            assert_eq!(again["closed_loop"]["chosen"], c["chosen"], "{again}");
        }
    }
    // (sampling pairs, closed-loop pairs, captures) of the white plane, then the dark texture.
    assert!(
        chosen[0].0 < chosen[1].0 && chosen[0].1 < chosen[1].1 && chosen[0].2 < chosen[1].2,
        "white plane, dark texture: {chosen:?}"
    );

    let d = dir.path().join("refused");
    let d = d.to_str().unwrap();
    for (extra, says) in [
        (
            &["--ntrain", "auto", "--method", "compennet++-cpu"][..],
            "--ntrain auto: the sampling rounds are scored with the linear rung",
        ),
        (
            &["--ntrain", "many"][..],
            "expected a number of sampling images, or \"auto\"",
        ),
    ] {
        let mut given = vec!["--rig", "virtual:white-plane"];
        given.extend_from_slice(extra);
        let o = compend(&calibrate_args(d, &given));
        assert_code(&o, 2);
        assert!(stderr(&o).contains(says), "{}", stderr(&o));
    }
    assert!(!Path::new(d).exists());
}
