//! The `compend sim` command line: listing and showing scenes, exporting setups (complete for
//! the offline commands, byte-identical for one seed), contact sheets.

use super::*;
use compend::raster::ImageSize;

#[test]
fn sim_list_and_show() {
    use common_cli::*;
    let o = compend(&["sim", "list"]);
    assert_code(&o, 0);
    let names: Vec<String> = stdout(&o).lines().map(str::to_string).collect();
    // The scenes, then the sets of projectors.
    assert_eq!(
        names,
        rig::BUILTIN
            .iter()
            .chain(rig::scene::SETS)
            .map(|s| s.to_string())
            .collect::<Vec<_>>()
    );

    let o = compend(&["sim", "show", "step"]);
    assert_code(&o, 0);
    let scene: rig::Scene = serde_json::from_str(&stdout(&o)).expect("JSON scene");
    assert_eq!(scene, rig::builtin("step").expect("built-in"));

    // --as-calibrated needs a calibrated model directory.
    let dir = tempfile::tempdir().expect("tempdir");
    let not_a_model = dir.path().join("nothing");
    let o = compend(&[
        "sim",
        "export",
        "--scene",
        "step",
        "--out",
        dir.path().join("root").to_str().unwrap(),
        "--as-calibrated",
        not_a_model.to_str().unwrap(),
    ]);
    assert_code(&o, 2);
    assert!(stderr(&o).contains("nothing"), "{}", stderr(&o));

    // A scene file whose sizes no machine could hold is refused before anything is made.
    let mut huge = scene.clone();
    huge.projector.width = 100_000_000;
    let path = dir.path().join("huge.json");
    std::fs::write(&path, serde_json::to_string(&huge).expect("JSON")).expect("scene file");
    let sheet = dir.path().join("sheet");
    let o = compend(&[
        "sim",
        "sheet",
        "--scene",
        path.to_str().unwrap(),
        "--out",
        sheet.to_str().unwrap(),
    ]);
    assert_code(&o, 2);
    assert!(
        stderr(&o).contains("projector.width/height 100000000x")
            && stderr(&o).contains("more than the 8192x8192 pixels")
            && stderr(&o).contains(&format!("{}: scene", path.display())),
        "{}",
        stderr(&o)
    );

    let o = compend(&["sim", "show", "no-such-scene"]);
    assert_code(&o, 2);
    assert!(
        stderr(&o).contains("white-plane"),
        "lists the scenes: {}",
        stderr(&o)
    );
}

/// Runs `compend sim export` for a tiny scene into `root`; it must succeed.
fn export_tiny(root: &std::path::Path, scene: &str, seed: u64, extra: &[&str]) {
    common_cli::assert_code(&export_tiny_output(root, scene, seed, extra), 0);
}

/// Runs `compend sim export` for a tiny scene into `root` and returns how it ended.
fn export_tiny_output(
    root: &std::path::Path,
    scene: &str,
    seed: u64,
    extra: &[&str],
) -> std::process::Output {
    use common_cli::*;
    let root = root.to_str().expect("utf-8 path");
    let seed = seed.to_string();
    let mut args = vec![
        "sim",
        "export",
        "--scene",
        scene,
        "--out",
        root,
        "--ntrain",
        "6",
        "--ntest",
        "2",
        "--camera",
        "80x60",
        "--projector",
        "100x75",
        "--network",
        "32",
        "--seed",
        &seed,
    ];
    args.extend_from_slice(extra);
    compend(&args)
}

/// Every file under `dir` (relative path, bytes), sorted.
fn files(dir: &std::path::Path) -> Vec<(std::path::PathBuf, Vec<u8>)> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).expect("readable folder") {
            let p = e.expect("entry").path();
            if p.is_dir() {
                stack.push(p);
            } else {
                let rel = p.strip_prefix(dir).expect("under dir").to_path_buf();
                out.push((rel, std::fs::read(&p).expect("readable file")));
            }
        }
    }
    out.sort();
    out
}

/// An exported setup is complete for the offline commands: `inspect` finds no problem, a
/// model trains on it, compensates its desired images, and `sim score` scores them on the rig
/// between the uncompensated row and the oracle.
#[test]
fn exported_setup_goes_through_the_offline_commands() {
    let dir = tempfile::tempdir().expect("temp dir");
    let root = dir.path();
    export_tiny(root, "curved", 2, &[]);
    let setup = root.join("curved");
    let s = setup.to_str().expect("utf-8");
    inspect_finds_no_problem(s);
    desired_images_lie_in_the_lit_area(&setup);
    train_and_compensate(&setup, s);
    // `compensate`'s images (a linear rung's, on its lattice) are no problem either.
    inspect_finds_no_problem(s);
    score_lies_between_uncompensated_and_oracle(s);
    score_writes_views_only_where_it_may(s);
}

/// `compend sim score --out`: the camera views of every row, into a folder outside the data
/// root; a second run replaces its own views, never a file it did not write.
fn score_writes_views_only_where_it_may(s: &str) {
    use common_cli::*;
    let dir = tempfile::tempdir().expect("temp dir");
    let views = dir.path().join("views");
    let score = |out: &std::path::Path| {
        compend(&[
            "sim",
            "score",
            "--setup",
            s,
            "--ntest",
            "2",
            "--out",
            out.to_str().expect("utf-8"),
        ])
    };
    for _ in 0..2 {
        assert_code(&score(&views), 0);
        for row in ["desired", "linear", "uncompensated", "oracle"] {
            assert!(views.join(row).join("img_0002.png").is_file(), "{row}");
        }
    }
    // A file of the user's where a view would go is kept, and nothing is written.
    let mine = dir.path().join("mine");
    std::fs::create_dir_all(mine.join("oracle")).expect("folder");
    std::fs::write(mine.join("oracle/img_0001.png"), "mine").expect("file");
    let o = score(&mine);
    assert_code(&o, 2);
    assert!(
        stderr(&o).contains("not written by `compend sim score`"),
        "{}",
        stderr(&o)
    );
    assert_eq!(
        std::fs::read_to_string(mine.join("oracle/img_0001.png")).expect("file"),
        "mine"
    );
    assert!(!mine.join("desired").exists());
    // Inside the data root, the views would be taken for models or captures.
    let inside = std::path::Path::new(s).join("prj-views");
    let o = score(&inside);
    assert_code(&o, 2);
    assert!(
        stderr(&o).contains("inside the data root"),
        "{}",
        stderr(&o)
    );
    assert!(!inside.exists());
    // Relative to a working folder in the data root, too.
    let o = compend_in(
        std::path::Path::new(s),
        &[
            "sim", "score", "--setup", ".", "--ntest", "2", "--out", "views",
        ],
    );
    assert_code(&o, 2);
    assert!(
        stderr(&o).contains("inside the data root"),
        "{}",
        stderr(&o)
    );
    assert!(!std::path::Path::new(s).join("views").exists());
    // Through a link into it.
    let lnk = dir.path().join("lnk");
    std::os::unix::fs::symlink(std::path::Path::new(s).join("cam"), &lnk).expect("link");
    for out in [lnk.join("views"), lnk.clone()] {
        let o = score(&out);
        assert_code(&o, 2);
        assert!(
            stderr(&o).contains("inside the data root"),
            "{}",
            stderr(&o)
        );
    }
    // A model named like a reference row would share its folder.
    let o = compend(&[
        "sim",
        "score",
        "--setup",
        s,
        "--ntest",
        "2",
        "--model",
        "oracle",
        "--out",
        dir.path().join("v2").to_str().expect("utf-8"),
    ]);
    assert_code(&o, 2);
    assert!(!dir.path().join("v2").exists());
}

/// `compend inspect` on the exported setup `s`: no problem, every capture counted.
fn inspect_finds_no_problem(s: &str) {
    use common_cli::*;
    let o = compend(&["inspect", "--setup", s, "--json"]);
    assert_code(&o, 0);
    let v: serde_json::Value = serde_json::from_str(&stdout(&o)).expect("JSON");
    assert_eq!(v["total_problems"], 0, "{v}");
    assert_eq!(
        v["captures"]["ref"], 126,
        "whole colour cube and the gray image"
    );
    assert_eq!(v["captures"]["train"], 6);
    assert_eq!(v["captures"]["sl"], v["projector_images"]["sl"]);
    assert_eq!(v["desired_test"], 2);
    assert_eq!(v["camera_size"]["width"], 80);
}

/// The record, and desired images placed in its displayable area (its edge carried
/// [`compend::fov::EDGE_MARGIN_PX`] outward, black beyond), which lies in the truly lit part of
/// the camera view.
fn desired_images_lie_in_the_lit_area(setup: &std::path::Path) {
    let record = rig::export::read_record(setup).expect("rig.json");
    assert_eq!(
        record.scene,
        rig::builtin("curved")
            .expect("built-in")
            .with_resolution(CAM, PRJ)
    );
    let area = record.displayable_area;
    let set = compend::dataset::Setup::open(setup, None).expect("setup");
    let z = &set.load_desired(None).expect("desired")[0];
    let m = compend::fov::EDGE_MARGIN_PX;
    let near = |x: usize, y: usize| {
        x + m >= area.x
            && y + m >= area.y
            && x < area.x + area.width + m
            && y < area.y + area.height + m
    };
    let (mut inside, mut margin, mut outside) = (0.0, 0.0, 0.0);
    for y in 0..CAM.height {
        for x in 0..CAM.width {
            let v: f32 = z.get(x, y).iter().sum();
            if area.contains(x, y) {
                inside += v;
            } else if near(x, y) {
                margin += v;
            } else {
                outside += v;
            }
        }
    }
    assert!(
        inside > 0.0 && margin > 0.0 && outside == 0.0,
        "{inside} {margin} {outside}"
    );
    let truth = tiny("curved", 2).lit_mask();
    let lit_in_area = (area.y..area.y + area.height)
        .flat_map(|y| (area.x..area.x + area.width).map(move |x| (x, y)))
        .filter(|&(x, y)| truth.get(x, y))
        .count();
    assert!(
        lit_in_area as f64 >= 0.97 * area.area() as f64,
        "area {area} mostly lit"
    );
}

/// Trains `linear` on the setup and compensates its desired test images into
/// `prj/cmp/test/linear`.
fn train_and_compensate(setup: &std::path::Path, s: &str) {
    use common_cli::*;
    let o = compend(&["train", "--setup", s, "--method", "linear"]);
    assert_code(&o, 0);
    let model = setup.join("models").join("linear");
    let desire = setup.join("cam").join("desire").join("test");
    let cmp = setup.join("prj").join("cmp").join("test").join("linear");
    let o = compend(&[
        "compensate",
        "--model",
        model.to_str().expect("utf-8"),
        "--input",
        desire.to_str().expect("utf-8"),
        "--out",
        cmp.to_str().expect("utf-8"),
    ]);
    assert_code(&o, 0);
}

/// `compend sim score`: the rows in order, the oracle on top, the trained model above the
/// uncompensated row.
fn score_lies_between_uncompensated_and_oracle(s: &str) {
    use common_cli::*;
    let o = compend(&["sim", "score", "--setup", s, "--json"]);
    assert_code(&o, 0);
    let v: serde_json::Value = serde_json::from_str(&stdout(&o)).expect("JSON");
    let rows = v["rows"].as_array().expect("rows");
    let names: Vec<&str> = rows
        .iter()
        .map(|r| r["name"].as_str().expect("name"))
        .collect();
    assert_eq!(
        names,
        [
            "uncompensated",
            "geometry-only",
            "linear",
            "oracle @ 32x32",
            "oracle"
        ]
    );
    let psnr = |k: usize| rows[k]["psnr"].as_f64().expect("psnr");
    assert_eq!(rows[4]["gap_db"].as_f64(), Some(0.0));
    assert!(
        psnr(4) > psnr(2) && psnr(4) > psnr(1) && psnr(1) > psnr(0),
        "{v}"
    );
    // Limiting the oracle to the network resolution can only cost (up to noise).
    assert!(psnr(3) <= psnr(4) + 0.1, "{v}");
    assert!(
        psnr(2) > psnr(0),
        "a trained model beats no compensation: {v}"
    );
    // Averaging frames as calibrate's verification does takes noise out of every row: the
    // oracle, whose error is mostly noise, gains.
    let o = compend(&["sim", "score", "--setup", s, "--json", "--average", "4"]);
    assert_code(&o, 0);
    let avg: serde_json::Value = serde_json::from_str(&stdout(&o)).expect("JSON");
    assert_eq!(avg["frames_averaged"], 4);
    let oracle = |v: &serde_json::Value| v["rows"][4]["psnr"].as_f64().expect("psnr");
    assert!(oracle(&avg) > oracle(&v) + 0.2, "{avg}\n{v}");
}

/// `sim export --loop-images`: closed-loop pairs after the sampling ones, each with its
/// desired view, that `train` uses by default; an export that would leave pairs that no longer
/// match their captures, or share the root's training images with another setup's, is refused
/// before anything is written.
#[test]
fn exported_closed_loop_pairs_and_their_guards() {
    use common_cli::*;
    let dir = tempfile::tempdir().expect("temp dir");
    let root = dir.path().join("r");
    export_tiny(&root, "curved", 3, &["--no-cube", "--loop-images", "4"]);
    let setup = root.join("curved");
    let listed = |d: &std::path::Path| {
        let mut v: Vec<String> = std::fs::read_dir(d)
            .expect("folder")
            .map(|e| e.expect("entry").file_name().to_string_lossy().into_owned())
            .collect();
        v.sort();
        v
    };
    assert_eq!(
        listed(&setup.join("cam/desire/train")),
        [
            "img_0007.png",
            "img_0008.png",
            "img_0009.png",
            "img_0010.png"
        ]
    );
    assert_eq!(listed(&setup.join("cam/raw/train")).len(), 10);
    assert_eq!(listed(&root.join("train")).len(), 10);
    let model = dir.path().join("m");
    let o = compend(&[
        "train",
        "--setup",
        setup.to_str().unwrap(),
        "--method",
        "linear",
        "--out",
        model.to_str().unwrap(),
    ]);
    assert_code(&o, 0);
    assert!(stderr(&o).contains("on 10 pairs"), "{}", stderr(&o));
    // The same export again replaces its own pairs.
    export_tiny(&root, "curved", 3, &["--no-cube", "--loop-images", "4"]);
    let before = files(&root);
    let refused = |extra: &[&str], says: &str| {
        let o = export_tiny_output(&root, "curved", 3, &[&["--no-cube"][..], extra].concat());
        assert_code(&o, 2);
        assert!(stderr(&o).contains(says), "{}", stderr(&o));
        assert!(files(&root) == before, "nothing written");
    };
    // Without them (or fewer), the earlier pairs would no longer match the new captures.
    refused(
        &[],
        "desire/train/img_0007.png: the desired view of a closed-loop pair",
    );
    refused(&["--loop-images", "2"], "desire/train/img_0009.png");
    // Another setup of the same root would overwrite this one's closed-loop images.
    refused(
        &["--setup", "other", "--loop-images", "2"],
        "another setup's closed-loop pairs",
    );
    // Captures that no export wrote (no rig.json: a calibration's, a recorded set's) are never
    // exported over, nor the root's images under them replaced by another seed's.
    std::fs::remove_file(setup.join("rig.json")).unwrap();
    let before = files(&root);
    let o = export_tiny_output(&root, "curved", 3, &["--no-cube", "--loop-images", "4"]);
    assert_code(&o, 2);
    assert!(stderr(&o).contains("no rig.json"), "{}", stderr(&o));
    assert!(files(&root) == before, "nothing written");
    let o = export_tiny_output(&root, "curved", 4, &["--no-cube", "--setup", "fresh"]);
    assert_code(&o, 2);
    assert!(stderr(&o).contains("another image"), "{}", stderr(&o));
    let after = files(&root);
    assert!(
        before.iter().all(|f| after.contains(f)),
        "an image was replaced"
    );
}

#[test]
fn identical_seeds_give_identical_files() {
    let dir = tempfile::tempdir().expect("temp dir");
    let (a, b, c) = (
        dir.path().join("a"),
        dir.path().join("b"),
        dir.path().join("c"),
    );
    export_tiny(&a, "defocus-noise", 7, &["--no-cube"]);
    export_tiny(&b, "defocus-noise", 7, &["--no-cube"]);
    export_tiny(&c, "defocus-noise", 8, &["--no-cube"]);
    let (fa, fb, fc) = (files(&a), files(&b), files(&c));
    assert!(fa.len() > 60, "{} files", fa.len());
    assert!(fa == fb, "same seed, same bytes");
    let capture = std::path::Path::new("defocus-noise/cam/raw/test/img_0001.png");
    let get = |f: &[(std::path::PathBuf, Vec<u8>)]| {
        f.iter()
            .find(|(p, _)| p == capture)
            .expect("test capture")
            .1
            .clone()
    };
    assert_ne!(get(&fa), get(&fc), "other seed, other capture");
}

#[test]
fn contact_sheet_per_scene() {
    use common_cli::*;
    let dir = tempfile::tempdir().expect("temp dir");
    let out = dir.path().to_str().expect("utf-8");
    let o = compend(&[
        "sim",
        "sheet",
        "--out",
        out,
        "--scene",
        "step",
        "--scene",
        "white-plane",
        "--camera",
        "80x60",
        "--projector",
        "100x75",
        "--network",
        "32",
    ]);
    assert_code(&o, 0);
    for name in ["step", "white-plane"] {
        let p = dir.path().join(format!("{name}.png"));
        let ImageSize {
            width: w,
            height: h,
        } = compend::pngio::png_size(&p).expect("a PNG per scene");
        assert!(w > 5 * 80 && h > 60, "five panels and captions: {w}x{h}");
    }
    // One line of scores per scene after the header.
    let text = stdout(&o);
    assert_eq!(text.lines().count(), 3, "{text}");
    assert!(text.lines().nth(1).expect("row").starts_with("step"));
}

#[test]
fn a_set_of_projectors_has_a_sheet_with_its_joint_ceiling() {
    use common_cli::*;
    let dir = tempfile::tempdir().expect("temp dir");
    let out = dir.path().to_str().expect("utf-8");
    let o = compend(&[
        "sim",
        "sheet",
        "--out",
        out,
        "--scene",
        "tiled",
        "--scene",
        "stacked",
        "--camera",
        "80x60",
        "--projector",
        "100x75",
        "--network",
        "32",
        "--seed",
        "5",
    ]);
    assert_code(&o, 0);
    for name in ["tiled", "stacked"] {
        let ImageSize {
            width: w,
            height: h,
        } = compend::pngio::png_size(&dir.path().join(format!("{name}.png")))
            .expect("the set's sheet");
        // Surface, each projector's white, all white, desired, projector 1 alone, joint.
        assert!(w > 7 * 80 && h > 60, "seven panels and captions: {w}x{h}");
    }
    let text = stdout(&o);
    let figure = |row: &str, after: &str| -> f64 {
        let rest = &row[row.find(after).expect(after) + after.len()..];
        let word = rest.split_whitespace().next().unwrap();
        word.trim_end_matches([')', ';']).parse().unwrap()
    };
    let row = |name: &str| text.lines().find(|l| l.starts_with(name)).expect(name);
    // Tiled: projector 1 alone lights half the picture, the set all of it.
    let tiled = row("tiled");
    let (alone, joint) = (
        figure(tiled, "projector 1 alone "),
        figure(tiled, "; joint "),
    );
    assert!(joint > alone + 3.0, "{tiled}");
    // Its pictures meet without a seam: the residual along the overlap edges is as away.
    assert!(figure(tiled, "seam ") < 2.0, "{tiled}");
    // Stacked: the joint ceiling is no worse, and the set's white is brighter than one's.
    let stacked = row("stacked");
    let (alone, joint) = (
        figure(stacked, "projector 1 alone "),
        figure(stacked, "; joint "),
    );
    assert!(joint >= alone, "{stacked}");
    let whites: Vec<f64> = stacked
        .match_indices("(white ")
        .map(|(i, _)| figure(&stacked[i..], "(white "))
        .collect();
    assert!(whites[1] > whites[0] * 1.15, "{stacked}");
    // A set is not something one projector's commands take.
    let o = compend(&[
        "sim",
        "export",
        "--scene",
        "tiled",
        "--out",
        dir.path().join("export").to_str().unwrap(),
    ]);
    assert_code(&o, 2);
    assert!(
        stderr(&o).contains("a set of 2 projectors"),
        "{}",
        stderr(&o)
    );
}

/// `compend calibrate --rig virtual:tiled` installs a set's model whose verification reports
/// the whole area and the seam figure; a scene whose second projector misses the camera exits
/// 2 naming it and installs nothing; another method than `linear` is refused.
#[test]
fn a_set_calibrates_from_the_command_line() {
    use common_cli::*;
    let dir = tempfile::tempdir().expect("temp dir");
    let arg = |p: &std::path::Path| p.to_str().expect("utf-8").to_string();
    let small = |scene: &str, out: &std::path::Path, extra: &[&str]| {
        let mut a: Vec<String> = [
            "calibrate",
            "--rig",
            scene,
            "--rig-camera",
            "96x72",
            "--projector",
            "100x75",
            "--network",
            "32",
            "--ntrain",
            "10",
            "--ntest",
            "4",
            "--verify",
            "3",
            "--loop-images",
            "0",
            "--rig-clock",
            "simulated",
            "--seed",
            "9",
        ]
        .iter()
        .map(|s| s.to_string())
        .collect();
        a.extend(["--out".into(), arg(out)]);
        a.extend(["--data".into(), arg(&out.with_extension("data"))]);
        a.extend(extra.iter().map(|s| s.to_string()));
        let refs: Vec<&str> = a.iter().map(String::as_str).collect();
        compend(&refs)
    };
    // At 96×72 the built-in framing leaves the first picture under two camera pixels from the
    // image's edge, where the camera's blur reaches it: a slightly wider view (a scene file)
    // keeps the whole set in sight; the built-in one is refused for it (below).
    let mut wide = compend::rig::scene::builtin("tiled").unwrap();
    wide.camera.hfov_deg *= 1.1;
    let wide_file = dir.path().join("wide.json");
    std::fs::write(&wide_file, serde_json::to_vec(&wide).unwrap()).unwrap();
    let out = dir.path().join("model");
    let o = small(&format!("virtual:{}", arg(&wide_file)), &out, &[]);
    assert_code(&o, 0);
    let err = stderr(&o);
    assert!(err.contains("the whole set on 3 test images"), "{err}");
    assert!(err.contains("seam figure"), "{err}");
    assert!(out.join("set.json").is_file(), "{err}");
    let meta: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("set.json")).unwrap()).unwrap();
    assert_eq!(meta["projectors"], 2);
    assert_eq!(meta["calibration"]["verification"]["passed"], true);
    // The set plays on its virtual rig: the joint pass per frame, the camera's view of both.
    let views = dir.path().join("views");
    let play = |extra: &[&str]| {
        let mut a = vec![
            "play",
            "--model",
            out.to_str().unwrap(),
            "--source",
            "pattern:bars?size=64x48&frames=2",
        ];
        a.extend(extra);
        compend(&a)
    };
    let o = play(&[]);
    assert_code(&o, 2);
    assert!(
        stderr(&o).contains("one window per projector's monitor: name them"),
        "{}",
        stderr(&o)
    );
    let o = play(&["--monitor", "0"]);
    assert_code(&o, 2);
    assert!(
        stderr(&o).contains("--monitor 0: 1 monitor(s) for a set of 2 projectors"),
        "{}",
        stderr(&o)
    );
    if crate::common::gpu().is_some() {
        let o = play(&["--rig", "virtual", "--out", views.to_str().unwrap()]);
        assert_code(&o, 0);
        assert!(views.join("cam_000002.png").is_file(), "{}", stderr(&o));
        assert!(!views.join("cam_000003.png").exists());
        // Each projector's compensated frames to a file of its own, offline, no display.
        let (left, right) = (dir.path().join("left.mp4"), dir.path().join("right.mp4"));
        let (l, r) = (
            format!("file:{}", left.display()),
            format!("file:{}", right.display()),
        );
        let o = play(&["--no-window", "--to", &l]);
        assert_code(&o, 2);
        assert!(
            stderr(&o).contains("--to given 1 time(s) for a set of 2 projectors"),
            "{}",
            stderr(&o)
        );
        let o = play(&["--no-window", "--to", &l, "--to", &l]);
        assert_code(&o, 2);
        assert!(
            stderr(&o).contains("is given for projectors 1 and 2: each projector needs"),
            "{}",
            stderr(&o)
        );
        assert!(!left.exists());
        let o = play(&["--no-window", "--to", &l, "--to", &r, "--json"]);
        assert_code(&o, 0);
        let v: serde_json::Value = serde_json::from_str(stdout(&o).trim()).unwrap();
        assert_eq!(v["written"], serde_json::json!([2, 2]), "{v}");
        assert_eq!(crate::media::decoded_frames(&left), 2);
        assert_eq!(crate::media::decoded_frames(&right), 2);
        set_plays_on_two_monitors(dir.path(), &out);
    }
    // Two projectors side by side that do not overlap: tiled without a blend, installed, with
    // no seam to figure.
    let mut apart = wide.clone();
    apart.projector.pose =
        compend::rig::scene::Pose::looking_at([-0.45, -0.05, 0.0], [-0.70, 0.0, 2.2], 0.3);
    apart.more_projectors[0].pose =
        compend::rig::scene::Pose::looking_at([0.45, -0.04, 0.0], [0.70, 0.0, 2.2], -0.5);
    apart.camera.hfov_deg *= 1.05;
    let apart_file = dir.path().join("apart.json");
    std::fs::write(&apart_file, serde_json::to_vec(&apart).unwrap()).unwrap();
    let apart_model = dir.path().join("apart-model");
    let o = small(&format!("virtual:{}", arg(&apart_file)), &apart_model, &[]);
    assert_code(&o, 0);
    assert!(
        stderr(&o).contains("the projectors do not overlap in the area: no seam figure"),
        "{}",
        stderr(&o)
    );
    assert!(apart_model.join("set.json").is_file());
    // The second projector turned away from the wall: named, exit 2, nothing installed.
    let mut scene = compend::rig::scene::builtin("tiled").unwrap();
    scene.more_projectors[0].pose =
        compend::rig::scene::Pose::looking_at([0.45, -0.04, 0.0], [0.45, 0.0, -2.0], 0.0);
    let file = dir.path().join("away.json");
    std::fs::write(&file, serde_json::to_vec(&scene).unwrap()).unwrap();
    let away = dir.path().join("away-model");
    let o = small(&format!("virtual:{}", arg(&file)), &away, &[]);
    assert_code(&o, 2);
    assert!(
        stderr(&o).contains("projector 2 lights nothing the camera sees"),
        "{}",
        stderr(&o)
    );
    assert!(!away.exists());
    // A camera zoomed in so that the set's pictures run off its view: named, exit 2; so is the
    // built-in framing at this size.
    let mut scene = compend::rig::scene::builtin("tiled").unwrap();
    scene.camera.hfov_deg *= 0.6;
    let file = dir.path().join("zoomed.json");
    std::fs::write(&file, serde_json::to_vec(&scene).unwrap()).unwrap();
    let o = small(&format!("virtual:{}", arg(&file)), &away, &[]);
    assert_code(&o, 2);
    assert!(
        stderr(&o).contains("projector 1's picture runs off the camera's view"),
        "{}",
        stderr(&o)
    );
    let o = small("virtual:tiled", &away, &[]);
    assert_code(&o, 2);
    assert!(
        stderr(&o).contains("picture runs off the camera's view"),
        "{}",
        stderr(&o)
    );
    assert!(!away.exists());
    let o = small("virtual:stacked", &away, &["--method", "auto"]);
    assert_code(&o, 2);
    assert!(
        stderr(&o).contains("calibrated with `linear`"),
        "{}",
        stderr(&o)
    );
    assert!(!away.exists());
}

/// The set of `a_set_calibrates_from_the_command_line` (projectors of 100×75) on two monitors of
/// an X server: every refresh on both, each monitor showing its projector's image of the joint
/// pass (the CPU reference `JointModel::apply`, stretched by `resize_bilinear`); a monitor that
/// is not there, or one named twice, exit 2 naming it.
fn set_plays_on_two_monitors(dir: &std::path::Path, model: &std::path::Path) {
    use common_cli::*;
    use compend::raster::{Rgb, Unspecified};
    let Some(x) = crate::window::XDummy::start(100, 75, 2) else {
        return;
    };
    let still = dir.join("still.png");
    let img: Rgb<Unspecified> = Rgb::from_fn(40, 30, |x, y| {
        [x as f32 / 39.0, y as f32 / 29.0, ((x + y) % 7) as f32 / 6.0]
    });
    compend::pngio::write_rgb(&still, &img).unwrap();
    let m = model.to_str().unwrap();
    let s = still.to_str().unwrap();
    let on_display = |monitors: &str, extra: &[&str]| {
        crate::common::output_within(
            std::process::Command::new(env!("CARGO_BIN_EXE_compend"))
                .args(["play", "--model", m, "--source", s, "--monitor", monitors])
                .args(extra)
                .env("DISPLAY", &x.display)
                .env_remove("WAYLAND_DISPLAY"),
        )
    };
    let o = on_display("0,1", &["--frames", "6", "--json"]);
    assert_code(&o, 0);
    let v: serde_json::Value = serde_json::from_str(stdout(&o).trim()).expect("JSON counts");
    assert_eq!(v["presented"], serde_json::json!([6, 6]), "{v}");
    assert_eq!(v["together"], 6, "{v}");
    assert_eq!(v["out_of_step"], 0, "{v}");
    assert_eq!(v["shown"], 1, "a still is one source frame: {v}");
    let o = on_display("0,5", &["--frames", "1"]);
    assert_code(&o, 2);
    let e = stderr(&o);
    assert!(
        e.contains("--monitor 5: no such monitor for projector 1") && e.contains("DUMMY1"),
        "{e}"
    );
    let o = on_display("DUMMY1,1", &["--frames", "1"]);
    assert_code(&o, 2);
    let e = stderr(&o);
    assert!(
        e.contains("projectors 0 and 1 both name monitor DUMMY1"),
        "{e}"
    );

    let _playing = crate::window::Running::start(
        &x.display,
        &[
            "play",
            "--model",
            m,
            "--source",
            s,
            "--monitor",
            "DUMMY0,DUMMY1",
        ],
        "first frame presented on every output",
    );
    let set = compend::model::set::SetModel::load(model).unwrap();
    let record = set.meta.calibration.clone().unwrap();
    let content: Rgb<Unspecified> = compend::source::read_image(&still).unwrap().to_image();
    let desired = compend::fov::place_in_area(
        &record.display_range.apply(&content),
        record.area,
        set.meta.camera_size,
    )
    .unwrap();
    let nets = set.joint().unwrap().apply(&desired).unwrap();
    for (k, net) in nets.iter().enumerate() {
        let want = compend::resize::resize_bilinear(net, 100, 75).map(|v| v.clamp(0.0, 1.0));
        let got = x.screenshot(dir, k);
        let diffs: Vec<f32> = want
            .data()
            .iter()
            .zip(got.data())
            .map(|(a, b)| (a - b).abs() * 255.0)
            .collect();
        let worst = diffs.iter().copied().fold(0.0, f32::max);
        let mean = diffs.iter().sum::<f32>() / diffs.len() as f32;
        eprintln!("monitor {k}: {mean:.3} mean, {worst:.2} worst (8-bit levels)");
        assert!(
            mean < 0.5 && worst <= 2.0,
            "monitor {k}: {mean} mean, {worst} worst"
        );
    }
    drop(_playing);
    // The second monitor switched to 50 Hz, then to another shape than the set was calibrated
    // for: each refused, named.
    let mode = |name: &str, clock: &str, w: usize, h: usize| {
        let t: Vec<String> = [w, w + 8, w + 16, w + 24, h, h + 2, h + 4, h + 6]
            .iter()
            .map(|v| v.to_string())
            .collect();
        let mut args = vec!["--newmode", name, clock];
        args.extend(t.iter().map(String::as_str));
        x.xrandr(&args);
        x.xrandr(&["--addmode", "DUMMY1", name]);
        x.xrandr(&["--output", "DUMMY1", "--mode", name]);
    };
    // 124 × 81 pixels a frame at 50 Hz.
    mode("100x75_50", "0.5022", 100, 75);
    let o = on_display("DUMMY0,DUMMY1", &["--frames", "1"]);
    assert_code(&o, 2);
    let e = stderr(&o);
    assert!(
        e.contains("the monitors refresh at different rates") && e.contains("DUMMY1 at 50.00 Hz"),
        "{e}"
    );
    // 104 × 81 pixels a frame at 60 Hz.
    mode("80x75", "0.5054", 80, 75);
    let o = on_display("DUMMY0,DUMMY1", &["--frames", "1"]);
    assert_code(&o, 2);
    let e = stderr(&o);
    assert!(
        e.contains(
            "--monitor DUMMY1: the monitor is 80x75, the set was calibrated for projectors of \
             100x75"
        ),
        "{e}"
    );
}
