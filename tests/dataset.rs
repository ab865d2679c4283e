//! Dataset layout (docs/architecture.md, "Dataset layout"): root discovery, counts, loading and
//! writing through the library, and `compend inspect` through the real binary. Every fixture is
//! generated here into a temporary folder: network 16×16, camera 24×20, 3 train and 2 test
//! pairs, nested setup `light1/pos1/curves`.

use std::fs;
use std::path::{Path, PathBuf};

use compend::Error;
use compend::dataset::{CaptureSet, DataRoot, ProjectorSet, Reference, Setup};
use compend::pngio;
use compend::raster::{CamImage, ImageSize, PrjImage, Rgb, Space};

use crate::common::{assert_code, compend, compend_in, stderr, stdout};

const NET: ImageSize = ImageSize::new(16, 16);
const CAM: ImageSize = ImageSize::new(24, 20);
const SETUP: &str = "light1/pos1/curves";

/// A distinct image for each (set, index): a gradient whose colour depends on both, exactly
/// representable in 8 bits so that loading returns what was written.
fn pattern<S: Space>(
    ImageSize {
        width: w,
        height: h,
    }: ImageSize,
    set: usize,
    index: usize,
) -> Rgb<S> {
    Rgb::from_fn(w, h, |x, y| {
        let v = |k: usize| ((k * 37 + set * 53 + index * 11) % 256) as f32 / 255.0;
        [v(x), v(y), v(x + y + 7)]
    })
}

struct Fixture {
    _tmp: tempfile::TempDir,
    root: PathBuf,
    setup: PathBuf,
}

impl Fixture {
    fn cam(&self, set: &str, name: &str) -> PathBuf {
        self.setup.join("cam/raw").join(set).join(name)
    }
}

/// A complete tiny setup written with the library's writers.
fn fixture() -> Fixture {
    let tmp = tempfile::tempdir().expect("tempdir");
    let root_path = tmp.path().join("data");
    let root = DataRoot::create(&root_path).expect("create root");
    for i in 1..=3 {
        root.write(ProjectorSet::Train, i, &pattern::<_>(NET, 1, i))
            .unwrap();
    }
    for i in 1..=2 {
        root.write(ProjectorSet::Test, i, &pattern::<_>(NET, 2, i))
            .unwrap();
    }
    root.write_gray_input(&PrjImage::filled(NET.width, NET.height, [0.3; 3]))
        .unwrap();
    let setup = Setup::create(&root, Path::new(SETUP)).expect("create setup");
    for r in Reference::ALL {
        setup
            .write_reference(r, &pattern::<_>(CAM, 10, r.index()))
            .unwrap();
    }
    for i in 1..=3 {
        setup
            .write_capture(CaptureSet::Train, i, &pattern::<_>(CAM, 3, i))
            .unwrap();
    }
    for i in 1..=2 {
        setup
            .write_capture(CaptureSet::Test, i, &pattern::<_>(CAM, 4, i))
            .unwrap();
        setup.write_desired(i, &pattern::<_>(CAM, 5, i)).unwrap();
        setup
            .write_compensation("linear", &pngio::indexed_name(i), &pattern::<_>(NET, 6, i))
            .unwrap();
    }
    let setup_path = root_path.join(SETUP);
    Fixture {
        _tmp: tmp,
        root: root_path,
        setup: setup_path,
    }
}

fn s(p: &Path) -> &str {
    p.to_str().expect("utf-8 temp path")
}

fn inspect_json(f: &Fixture) -> (std::process::Output, serde_json::Value) {
    let o = compend(&["inspect", "--setup", s(&f.setup), "--json"]);
    let v = serde_json::from_str(stdout(&o).trim()).unwrap_or(serde_json::Value::Null);
    (o, v)
}

// ---------------------------------------------------------------- library

#[test]
fn writers_produce_the_official_layout() {
    let f = fixture();
    for p in [
        "train/img_0001.png",
        "train/img_0003.png",
        "test/img_0002.png",
        "ref/img_gray.png",
        "light1/pos1/curves/cam/raw/ref/img_0001.png",
        "light1/pos1/curves/cam/raw/ref/img_0125.png",
        "light1/pos1/curves/cam/raw/ref/img_0126.png",
        "light1/pos1/curves/cam/raw/train/img_0003.png",
        "light1/pos1/curves/cam/raw/test/img_0002.png",
        "light1/pos1/curves/cam/desire/test/img_0002.png",
        "light1/pos1/curves/prj/cmp/test/linear/img_0002.png",
    ] {
        assert!(f.root.join(p).is_file(), "{p} not written");
    }
    assert!(!f.root.join("train/img_0004.png").exists());
}

#[test]
fn root_is_the_nearest_ancestor_with_train_and_test() {
    let f = fixture();
    let setup = Setup::open(&f.setup, None).expect("open");
    assert_eq!(setup.root().path(), f.root);
    assert_eq!(setup.relative(), PathBuf::from(SETUP));

    // A nearer folder with train/ and test/ wins over the real root...
    fs::create_dir_all(f.root.join("light1/train")).unwrap();
    fs::create_dir_all(f.root.join("light1/test")).unwrap();
    let near = Setup::open(&f.setup, None).expect("open");
    assert_eq!(near.root().path(), f.root.join("light1"));
    assert_eq!(near.relative(), PathBuf::from("pos1/curves"));
    // ...unless the root is named explicitly.
    let explicit = Setup::open(&f.setup, Some(&f.root)).expect("open with --data");
    assert_eq!(explicit.root().path(), f.root);
    // train/ alone does not make a root.
    fs::remove_dir(f.root.join("light1/test")).unwrap();
    assert_eq!(Setup::open(&f.setup, None).unwrap().root().path(), f.root);
}

#[test]
fn no_root_found_is_an_input_error_naming_the_setup() {
    let tmp = tempfile::tempdir().unwrap();
    let setup = tmp.path().join("lonely/setup");
    fs::create_dir_all(setup.join("cam/raw/ref")).unwrap();
    let err = Setup::open(&setup, None).expect_err("no root");
    assert!(matches!(err, Error::Input(_)), "{err:?}");
    assert_eq!(err.exit_code(), 2);
    assert!(err.to_string().contains(s(&setup)), "{err}");

    // An explicit root without test/ is refused too, naming it.
    fs::create_dir_all(tmp.path().join("lonely/train")).unwrap();
    let err = Setup::open(&setup, Some(&tmp.path().join("lonely"))).expect_err("not a root");
    assert!(matches!(err, Error::Input(_)), "{err:?}");
    assert!(err.to_string().contains("test/"), "{err}");

    // A setup folder that does not exist is a missing path.
    let err = Setup::open(&tmp.path().join("nope"), None).expect_err("missing");
    assert!(matches!(err, Error::Missing { .. }), "{err:?}");
}

#[test]
fn a_setup_outside_an_explicit_root_works() {
    let f = fixture();
    let elsewhere = f._tmp.path().join("elsewhere/setup");
    fs::create_dir_all(elsewhere.parent().unwrap()).unwrap();
    fs::rename(&f.setup, &elsewhere).unwrap();
    assert!(Setup::open(&elsewhere, None).is_err());
    let setup = Setup::open(&elsewhere, Some(&f.root)).unwrap();
    assert_eq!(setup.relative(), elsewhere);
    assert_eq!(setup.load_train(None).unwrap().captures.len(), 3);
}

#[test]
fn info_counts_and_sizes() {
    let f = fixture();
    let setup = Setup::open(&f.setup, None).unwrap();
    let info = setup.info().expect("info");
    assert_eq!(info.root, f.root);
    assert_eq!(info.setup, PathBuf::from(SETUP));
    assert_eq!(info.camera_size, Some(CAM));
    assert_eq!(info.network_size, Some(NET));
    assert_eq!(info.projector_size, None);
    assert_eq!(
        (
            info.captures.train,
            info.captures.test,
            info.captures.refs,
            info.captures.sl
        ),
        (3, 2, 3, 0)
    );
    assert_eq!(
        (
            info.projector_images.train,
            info.projector_images.test,
            info.projector_images.refs,
            info.projector_images.sl
        ),
        (3, 2, 0, 0)
    );
    assert!(info.references.black && info.references.white && info.references.gray);
    assert!(info.gray_input);
    assert_eq!(info.desired_test, Some(2));
    assert_eq!(info.compensated, vec!["linear".to_string()]);
    assert_eq!(setup.count(CaptureSet::Train).unwrap(), 3);
    assert_eq!(setup.root().count(ProjectorSet::Test).unwrap(), 2);
    assert_eq!(setup.root().count(ProjectorSet::Sl).unwrap(), 0);
    assert_eq!(setup.camera_size().unwrap(), CAM);
    assert_eq!(setup.root().network_size().unwrap(), NET);
}

#[test]
fn loading_returns_what_was_written() {
    let f = fixture();
    let setup = Setup::open(&f.setup, None).unwrap();
    let pairs = setup.load_train(Some(2)).expect("2 training pairs");
    assert_eq!(pairs.captures.len(), 2);
    assert_eq!(pairs.inputs.len(), 2);
    for i in 0..2 {
        assert_eq!(pairs.captures[i], pattern::<_>(CAM, 3, i + 1));
        assert_eq!(pairs.inputs[i], pattern::<_>(NET, 1, i + 1));
    }
    let all = setup.load_train(None).unwrap();
    assert_eq!(all.captures.len(), 3);
    assert_eq!(all.captures[2], pattern::<_>(CAM, 3, 3));
    let test = setup.load_test(None).unwrap();
    assert_eq!(test.inputs[1], pattern::<_>(NET, 2, 2));
    assert_eq!(test.captures[1], pattern::<_>(CAM, 4, 2));
    let gray: CamImage = setup.load_reference(Reference::Gray).unwrap();
    assert_eq!(gray, pattern::<_>(CAM, 10, 126));
    let black = setup.load_reference(Reference::Black).unwrap();
    assert_eq!(black, pattern::<_>(CAM, 10, 1));
    let desired = setup.load_desired(None).unwrap();
    assert_eq!(desired.len(), 2);
    assert_eq!(desired[0], pattern::<_>(CAM, 5, 1));
    let x0 = setup.root().load_gray_input().unwrap();
    assert_eq!(x0.get(3, 4), [77.0 / 255.0; 3]); // 0.3 rounds to level 77 (76.5 → 77)
    assert!(
        setup
            .load_captures(CaptureSet::Sl, None)
            .unwrap()
            .is_empty()
    );
}

#[test]
fn asking_for_more_pairs_than_exist_names_the_folder_and_both_counts() {
    let f = fixture();
    let setup = Setup::open(&f.setup, None).unwrap();
    let err = setup.load_train(Some(5)).expect_err("only 3 exist");
    assert!(matches!(err, Error::Input(_)), "{err:?}");
    let msg = err.to_string();
    assert!(msg.contains(s(&f.setup.join("cam/raw/train"))), "{msg}");
    assert!(
        msg.contains("holds 3") && msg.contains("5 were requested"),
        "{msg}"
    );

    // Projector side short: 3 captures but only 2 projector images.
    fs::remove_file(f.root.join("train/img_0003.png")).unwrap();
    let err = setup
        .load_train(Some(3))
        .expect_err("only 2 projector images");
    let msg = err.to_string();
    assert!(msg.contains(s(&f.root.join("train"))), "{msg}");
    assert!(
        msg.contains("holds 2") && msg.contains("3 were requested"),
        "{msg}"
    );
}

#[test]
fn loading_reports_missing_corrupt_and_mis_sized_files() {
    let f = fixture();
    let setup = Setup::open(&f.setup, None).unwrap();

    let odd = f.cam("train", "img_0002.png");
    pngio::write_rgb(&odd, &CamImage::new(30, 20)).unwrap();
    match setup.load_train(Some(3)).expect_err("mis-sized") {
        Error::Size {
            path,
            got,
            expected,
            ..
        } => {
            assert_eq!(path, odd);
            assert_eq!(got, ImageSize::new(30, 20));
            assert_eq!(expected, CAM);
        }
        e => panic!("expected a size error, got {e:?}"),
    }
    // The first pair alone is still fine.
    assert!(setup.load_train(Some(1)).is_ok());

    fs::write(&odd, b"not a png at all").unwrap();
    match setup
        .load_captures(CaptureSet::Train, None)
        .expect_err("corrupt")
    {
        Error::Decode { path, .. } => assert_eq!(path, odd),
        e => panic!("expected a decode error, got {e:?}"),
    }

    fs::remove_file(f.cam("ref", "img_0126.png")).unwrap();
    match setup.load_reference(Reference::Gray).expect_err("missing") {
        e @ Error::Missing { .. } => {
            assert_eq!(e.exit_code(), 2);
            assert!(e.to_string().contains("img_0126.png"), "{e}");
        }
        e => panic!("expected a missing-file error, got {e:?}"),
    }
}

#[test]
fn a_gap_is_an_error_naming_the_first_missing_file() {
    let f = fixture();
    let setup = Setup::open(&f.setup, None).unwrap();
    fs::remove_file(f.cam("train", "img_0002.png")).unwrap();
    let err = setup.count(CaptureSet::Train).expect_err("gap");
    assert!(matches!(err, Error::Missing { .. }), "{err:?}");
    let msg = err.to_string();
    assert!(msg.contains(s(&f.cam("train", "img_0002.png"))), "{msg}");
    assert!(msg.contains("img_0003.png exists"), "{msg}");
    assert!(setup.load_train(Some(1)).is_err());
    // Reference captures are addressed by name: no contiguity needed there.
    assert_eq!(setup.count(CaptureSet::Ref).unwrap(), 3);
    // Removing the last one closes the gap.
    fs::remove_file(f.cam("train", "img_0003.png")).unwrap();
    assert_eq!(setup.count(CaptureSet::Train).unwrap(), 1);
}

#[test]
fn writers_refuse_bad_names_and_index_zero() {
    let f = fixture();
    let setup = Setup::open(&f.setup, None).unwrap();
    let img = PrjImage::new(NET.width, NET.height);
    for (model, name) in [
        ("../x", "img_0001.png"),
        ("m", "../img_0001.png"),
        ("", "a.png"),
    ] {
        let err = setup
            .write_compensation(model, name, &img)
            .expect_err("refused");
        assert!(matches!(err, Error::Input(_)), "{err:?}");
    }
    assert!(
        setup
            .write_capture(CaptureSet::Train, 0, &CamImage::new(CAM.width, CAM.height))
            .is_err()
    );
    assert!(Setup::create(setup.root(), Path::new("../out")).is_err());
    assert!(Setup::create(setup.root(), Path::new("/abs")).is_err());
}

#[test]
fn validate_collects_every_problem() {
    let f = fixture();
    fs::write(f.cam("train", "img_0001.png"), b"garbage").unwrap();
    pngio::write_rgb(&f.cam("test", "img_0002.png"), &CamImage::new(24, 21)).unwrap();
    pngio::write_rgb(
        &f.root.join("test/img_0001.png"),
        &PrjImage::new(NET.width + 4, NET.height),
    )
    .unwrap();
    let setup = Setup::open(&f.setup, None).unwrap();
    let v = setup.validate(50);
    assert_eq!(v.total_problems, 3, "{:#?}", v.problems);
    let all: Vec<String> = v.problems.iter().map(|e| e.to_string()).collect();
    for needle in [
        "test/img_0001.png: image is 20x16, expected 16x16",
        "cam/raw/train/img_0001.png: not a readable PNG",
        "cam/raw/test/img_0002.png: image is 24x21, expected 24x20",
    ] {
        assert!(
            all.iter().any(|m| m.contains(needle)),
            "{needle} in {all:#?}"
        );
    }
    // The header-level summary stops at the first problem.
    assert!(setup.info().is_err());
    // The cap limits the list, not the count.
    let capped = setup.validate(1);
    assert_eq!((capped.problems.len(), capped.total_problems), (1, 3));
}

#[test]
fn size_of_a_space_falls_back_when_its_reference_is_gone() {
    let f = fixture();
    fs::remove_file(f.cam("ref", "img_0001.png")).unwrap();
    pngio::write_rgb(&f.cam("train", "img_0003.png"), &CamImage::new(8, 8)).unwrap();
    let v = Setup::open(&f.setup, None).unwrap().validate(50);
    assert_eq!(v.info.camera_size, None);
    assert!(!v.info.references.black);
    let all: Vec<String> = v.problems.iter().map(|e| e.to_string()).collect();
    assert_eq!(v.total_problems, 2, "{all:#?}");
    assert!(all[0].contains("img_0001.png: missing"), "{all:#?}");
    assert!(
        all[1].contains("img_0003.png: image is 8x8, expected 24x20"),
        "{all:#?}"
    );
}

#[test]
fn captures_without_projector_images_and_odd_network_sizes_are_problems() {
    let f = fixture();
    fs::remove_file(f.root.join("train/img_0003.png")).unwrap();
    let v = Setup::open(&f.setup, None).unwrap().validate(50);
    assert_eq!(v.total_problems, 1, "{:#?}", v.problems);
    let msg = v.problems[0].to_string();
    assert!(
        msg.contains(&format!(
            "{}: a capture without a projector image",
            f.cam("train", "img_0003.png").display()
        )),
        "{msg}"
    );
    assert!(msg.contains("holds only 2 images"), "{msg}");

    let tmp = tempfile::tempdir().unwrap();
    let root = DataRoot::create(tmp.path()).unwrap();
    root.write(ProjectorSet::Train, 1, &PrjImage::new(10, 12))
        .unwrap();
    let setup = Setup::create(&root, Path::new("s")).unwrap();
    for r in Reference::ALL {
        setup.write_reference(r, &CamImage::new(8, 8)).unwrap();
    }
    let v = setup.validate(50);
    assert_eq!(v.total_problems, 1, "{:#?}", v.problems);
    assert!(v.problems[0].to_string().contains("divisible by 4"));
}

// ---------------------------------------------------------------- CLI

#[test]
fn inspect_good_setup_prints_the_json_summary() {
    let f = fixture();
    let (o, v) = inspect_json(&f);
    assert_code(&o, 0);
    assert_eq!(v["ok"], true);
    assert_eq!(v["root"], s(&f.root));
    assert_eq!(v["setup"], SETUP);
    assert_eq!(v["camera_size"]["width"], 24);
    assert_eq!(v["camera_size"]["height"], 20);
    assert_eq!(v["network_size"]["width"], 16);
    assert_eq!(v["network_size"]["height"], 16);
    assert!(v["projector_size"].is_null());
    assert_eq!(v["captures"]["train"], 3);
    assert_eq!(v["captures"]["test"], 2);
    assert_eq!(v["captures"]["ref"], 3);
    assert_eq!(v["captures"]["sl"], 0);
    assert_eq!(v["projector_images"]["train"], 3);
    assert_eq!(v["projector_images"]["test"], 2);
    assert_eq!(v["references"]["gray"], true);
    assert_eq!(v["gray_input"], true);
    assert_eq!(v["desired_test"], 2);
    assert_eq!(v["compensated"], serde_json::json!(["linear"]));
    // 3+2 root + gray input + 2 compensation + 3 ref + 3 train + 2 test + 2 desired
    assert_eq!(v["images_checked"], 18);
    assert_eq!(v["problems"], serde_json::json!([]));
}

#[test]
fn inspect_human_output_and_relative_paths() {
    let f = fixture();
    // Relative --setup resolved against the working folder; explicit --data as well.
    let o = compend_in(&f.root, &["inspect", "--setup", SETUP, "--data", "."]);
    assert_code(&o, 0);
    let out = stdout(&o);
    assert!(out.contains("camera size   24x20"), "{out}");
    assert!(out.contains("network size  16x16"), "{out}");
    assert!(out.contains(&format!("setup         {SETUP}")), "{out}");
    let o = compend_in(
        &f.root.join("light1"),
        &["inspect", "--setup", "pos1/curves"],
    );
    assert_code(&o, 0);
    assert!(stdout(&o).contains(&format!("data root     {}", f.root.display())));
}

#[test]
fn inspect_without_a_root_exits_2_naming_the_setup() {
    let tmp = tempfile::tempdir().unwrap();
    let setup = tmp.path().join("orphan");
    fs::create_dir_all(&setup).unwrap();
    let o = compend(&["inspect", "--setup", s(&setup)]);
    assert_code(&o, 2);
    assert!(stderr(&o).contains(s(&setup)), "{}", stderr(&o));
    assert!(stderr(&o).contains("--data"), "{}", stderr(&o));
}

#[test]
fn inspect_missing_reference_exits_2_naming_it() {
    let f = fixture();
    let gone = f.cam("ref", "img_0125.png");
    fs::remove_file(&gone).unwrap();
    let (o, v) = inspect_json(&f);
    assert_code(&o, 2);
    let err = stderr(&o);
    assert!(err.contains(s(&gone)), "{err}");
    assert!(err.contains("white reference"), "{err}");
    assert_eq!(v["ok"], false);
    assert_eq!(v["references"]["white"], false);
    assert_eq!(v["total_problems"], 1);
}

#[test]
fn inspect_corrupt_png_exits_2_naming_it() {
    let f = fixture();
    let bad = f.root.join(SETUP).join("cam/desire/test/img_0001.png");
    fs::write(&bad, [0x89, b'P', b'N', b'G', 0, 1, 2, 3, 4, 5, 6, 7, 8]).unwrap();
    let o = compend(&["inspect", "--setup", s(&f.setup)]);
    assert_code(&o, 2);
    let err = stderr(&o);
    assert!(
        err.contains(&format!("{}: not a readable PNG", bad.display())),
        "{err}"
    );
}

#[test]
fn inspect_mis_sized_capture_exits_2_naming_it_and_both_sizes() {
    let f = fixture();
    let odd = f.cam("train", "img_0002.png");
    pngio::write_rgb(&odd, &CamImage::new(20, 24)).unwrap();
    let o = compend(&["inspect", "--setup", s(&f.setup)]);
    assert_code(&o, 2);
    let err = stderr(&o);
    assert!(
        err.contains(&format!(
            "{}: image is 20x24, expected 24x20",
            odd.display()
        )),
        "{err}"
    );
    assert!(err.contains("black reference capture"), "{err}");
}

#[test]
fn inspect_gap_in_train_captures_exits_2_naming_the_first_missing_file() {
    let f = fixture();
    pngio::write_rgb(
        &f.cam("train", "img_0006.png"),
        &pattern::<compend::raster::Camera>(CAM, 3, 6),
    )
    .unwrap();
    let o = compend(&["inspect", "--setup", s(&f.setup)]);
    assert_code(&o, 2);
    let err = stderr(&o);
    assert!(err.contains(s(&f.cam("train", "img_0004.png"))), "{err}");
    assert!(err.contains("img_0006.png exists"), "{err}");
    // The later capture also has no projector image: both problems are reported.
    assert!(
        err.contains(&format!(
            "{}: a capture without a projector image",
            f.cam("train", "img_0006.png").display()
        )),
        "{err}"
    );
    assert!(err.contains("2 problems"), "{err}");
}

#[test]
fn inspect_lists_fifty_problems_and_counts_each_once() {
    let f = fixture();
    // 55 damaged colour-cube references (the black and white ones, 1 and 2, stay readable).
    for i in 3..58 {
        fs::write(f.cam("ref", &format!("img_{i:04}.png")), b"garbage").unwrap();
    }
    let (o, v) = inspect_json(&f);
    assert_code(&o, 2);
    assert_eq!(v["total_problems"], 55, "{v}");
    let listed = v["problems"].as_array().unwrap();
    assert_eq!(listed.len(), 50, "{v}");
    assert!(
        listed[0].as_str().unwrap().contains("ref/img_0003.png"),
        "{v}"
    );
    assert!(stderr(&o).contains("55 problems"), "{}", stderr(&o));
}

#[test]
fn inspect_reports_all_problems_at_once() {
    let f = fixture();
    fs::write(f.cam("train", "img_0001.png"), b"garbage").unwrap();
    fs::remove_file(f.cam("ref", "img_0126.png")).unwrap();
    pngio::write_rgb(&f.cam("test", "img_0001.png"), &CamImage::new(4, 4)).unwrap();
    let (o, v) = inspect_json(&f);
    assert_code(&o, 2);
    assert_eq!(v["total_problems"], 3, "{v}");
    let err = stderr(&o);
    for name in [
        "train/img_0001.png",
        "ref/img_0126.png",
        "test/img_0001.png",
    ] {
        assert!(err.contains(name), "{name} in {err}");
    }
}
