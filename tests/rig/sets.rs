//! Sets of projectors on the virtual rig: light adds, a tiled set covers more than either of
//! its projectors, and the set's joint ceiling reaches what one projector cannot.

use compend::raster::{CamImage, Camera, ImageSize, Mask};
use compend::rig::scene::builtin;
use compend::rig::{OracleOptions, Phase, SetSimulator, Simulator};

/// A built-in set at 64×48 camera and 80×60 projector pixels.
fn small(name: &str) -> SetSimulator {
    let scene = builtin(name)
        .unwrap()
        .with_resolution(ImageSize::new(64, 48), ImageSize::new(80, 60));
    SetSimulator::new(&scene, 3, Phase::Calibration).unwrap()
}

fn count(m: &Mask<Camera>) -> usize {
    m.data().iter().filter(|&&v| v).count()
}

#[test]
fn light_adds_and_the_room_is_counted_once() {
    let set = small("stacked");
    let [black, white] = [0.0, 1.0].map(|v| set.uniform(v));
    let both_black = set.clean_signal(&black).unwrap();
    let first_white = set
        .clean_signal(&[white[0].clone(), black[1].clone()])
        .unwrap();
    // Projector 1's own light, from its simulator alone, is what it adds in the set.
    let one = &set.projectors()[0];
    let alone_white = one.clean_signal(&white[0]).unwrap();
    let alone_black = one.clean_signal(&black[0]).unwrap();
    let mut worst = 0f32;
    for i in 0..both_black.len() {
        let in_set = first_white[i] - both_black[i];
        let alone = alone_white[i] - alone_black[i];
        worst = worst.max((in_set - alone).abs());
    }
    assert!(
        worst < 1e-5,
        "projector 1 adds {worst} more or less in the set"
    );
    // Both black: each projector's black and the room's light once, more than one's.
    let one_black: f32 = alone_black.iter().sum();
    let set_black: f32 = both_black.iter().sum();
    assert!(set_black > one_black, "{set_black} against {one_black}");
    // The wrong number of images is refused.
    assert!(set.clean_signal(&black[..1]).is_err());
}

#[test]
fn a_tiled_set_covers_more_than_either_and_overlaps_by_a_fraction() {
    let set = small("tiled");
    let each: Vec<usize> = set
        .projectors()
        .iter()
        .map(|s| count(&s.lit_mask()))
        .collect();
    let union = count(&set.lit_union());
    let overlap = count(&set.overlap());
    assert!(union > each[0].max(each[1]) * 3 / 2, "{union} of {each:?}");
    // About a fifth of each picture is lit by both (the camera sees it foreshortened).
    for &e in &each {
        let share = overlap as f64 / e as f64;
        assert!((0.08..0.35).contains(&share), "overlap {overlap} of {e}");
    }
    // A single-projector simulator refuses the set, saying what shows it.
    let e = Simulator::new(set.scene(), 0, Phase::Calibration)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("a set of 2 projectors") && e.contains("sim sheet"),
        "{e}"
    );
}

#[test]
fn the_joint_oracle_reaches_what_one_projector_cannot() {
    let set = small("stacked");
    let one = &set.projectors()[0];
    let mask = one.lit_mask();
    // A bright grey on the dark texture: beyond one projector in most places.
    let ImageSize { width, height } = set.camera_size();
    let desired = CamImage::filled(width, height, [0.55, 0.55, 0.55]);
    let opts = OracleOptions { iterations: 30 };
    let error = |seen: &CamImage| -> f64 {
        let mut sum = 0f64;
        let mut n = 0usize;
        for i in 0..width * height {
            if mask.data()[i] {
                for c in 0..3 {
                    let d = (seen.data()[i * 3 + c] - desired.data()[i * 3 + c]) as f64;
                    sum += d * d;
                    n += 1;
                }
            }
        }
        sum / n as f64
    };
    // Projector 1 alone, the other black: the single-projector ceiling on its own.
    let alone = one.oracle(&desired, &mask, opts).unwrap();
    let black = set.uniform(0.0);
    let alone_err = error(&set.expected(&[alone, black[1].clone()]).unwrap());
    let joint = set.oracle(&desired, &mask, opts).unwrap();
    assert_eq!(joint.len(), 2);
    let joint_err = error(&set.expected(&joint).unwrap());
    assert!(
        joint_err < 0.7 * alone_err,
        "together {joint_err:.5}, projector 1 alone {alone_err:.5} (mean squared error)"
    );
}

#[test]
fn a_projector_the_camera_does_not_see_is_named() {
    let mut scene = builtin("tiled")
        .unwrap()
        .with_resolution(ImageSize::new(64, 48), ImageSize::new(80, 60));
    // The second projector turned to face away from the wall.
    scene.more_projectors[0].pose =
        compend::rig::scene::Pose::looking_at([0.45, -0.04, 0.0], [0.45, 0.0, -2.0], 0.0);
    let e = SetSimulator::new(&scene, 0, Phase::Calibration)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("projector 2 lights nothing the camera sees"),
        "{e}"
    );
}

#[test]
fn a_seam_shows_where_two_pictures_add_and_not_with_the_joint_ceiling() {
    let scene = builtin("tiled")
        .unwrap()
        .with_resolution(ImageSize::new(96, 72), ImageSize::new(100, 75));
    let set = SetSimulator::new(&scene, 2, Phase::Calibration).unwrap();
    let region = set.lit_union();
    let (band, away) = set.seam_regions(&region, 2);
    let count = |m: &Mask<Camera>| m.data().iter().filter(|&&v| v).count();
    assert!(
        count(&band) > 20 && count(&away) > 200,
        "{} {}",
        count(&band),
        count(&away)
    );
    let ImageSize { width, height } = set.camera_size();
    let desired = CamImage::filled(width, height, [0.35, 0.35, 0.35]);
    let opts = OracleOptions { iterations: 40 };
    let figure = |images: &[compend::raster::PrjImage]| {
        let seen = set.expected(images).unwrap();
        compend::metrics::seam_figure(&seen, &desired, band.data(), away.data()).unwrap()
    };
    // Jointly compensated: the overlap is shared, nothing marks the edges.
    let joint = figure(&set.oracle(&desired, &region, opts).unwrap());
    // Each projector compensated on its own for its own picture, ignoring the other: where
    // the pictures overlap the light adds, a bright band along the edges.
    let apart: Vec<_> = set
        .projectors()
        .iter()
        .map(|s| s.oracle(&desired, &s.lit_mask(), opts).unwrap())
        .collect();
    let apart = figure(&apart);
    assert!(joint.ratio() < 3.0, "joint {joint:?}");
    assert!(
        apart.ratio() > 4.0 * joint.ratio(),
        "apart {apart:?}, joint {joint:?}"
    );
}

#[test]
fn one_projector_of_a_set_is_simulated_alone_with_the_others_black() {
    let scene = builtin("tiled")
        .unwrap()
        .with_resolution(ImageSize::new(64, 48), ImageSize::new(80, 60));
    let set = SetSimulator::new(&scene, 4, Phase::Calibration).unwrap();
    let black = set.uniform(0.0);
    let white = set.uniform(1.0);
    for k in 0..2 {
        let one = set.with_others_black(k).unwrap();
        let mut shown = black.clone();
        shown[k] = white[k].clone();
        let in_set = set.clean_signal(&shown).unwrap();
        let alone = one.clean_signal(&white[k]).unwrap();
        let worst = in_set
            .iter()
            .zip(&alone)
            .map(|(a, b)| (a - b).abs())
            .fold(0f32, f32::max);
        assert!(worst < 1e-5, "projector {}: {worst}", k + 1);
        // A capture with the same frame index draws the same noise.
        let a = set.capture(&shown, 9).unwrap();
        let b = one.capture(&white[k], 9).unwrap();
        let off = a
            .data()
            .iter()
            .zip(b.data())
            .filter(|(x, y)| (*x - *y).abs() > 0.5 / 255.0)
            .count();
        assert!(off * 1000 <= a.data().len(), "{off} values differ");
    }
    assert!(set.with_others_black(2).is_err());
}

/// A set calibrated as a whole (`calibrate::set`): each projector as today with the others
/// black (its field of view is its own picture), then the joint model checked in closed loop
/// over the set's displayable area: better than either projector alone, no seam; its model
/// directory saves and loads, and a set's directory is not taken for one projector's model.
#[test]
fn a_set_calibrates_and_verifies_as_a_whole() {
    use compend::calibrate::SamplingCount;
    use compend::config::Config;
    use compend::model::set::SetModel;
    use compend::rig::VirtualRig;

    // At 96×72 the built-in framing leaves the first picture under two camera pixels from the
    // image's edge, where the camera's blur reaches it: a slightly wider view keeps the whole
    // set in sight (the calibration refuses a picture that runs off the view).
    let mut scene = builtin("tiled")
        .unwrap()
        .with_resolution(ImageSize::new(96, 72), ImageSize::new(100, 75));
    scene.camera.hfov_deg *= 1.1;
    let set = SetSimulator::new(&scene, 6, Phase::Calibration).unwrap();
    let config = Config::defaults();
    let mut c = config.calibration.clone();
    c.ntrain = SamplingCount::Count(10);
    c.ntest = 4;
    c.verify = 3;
    c.network = ImageSize::new(32, 32);
    let opts = compend::rigs::calibration_options(
        &config.rig,
        &c,
        None,
        ImageSize::new(100, 75),
        None,
        None,
    );
    let rig = VirtualRig::new(&scene, 6).unwrap();
    assert_eq!(rig.outputs(), 2);
    let displays = vec![rig.output(0).unwrap(), rig.output(1).unwrap()];
    let dir = tempfile::tempdir().unwrap();
    let mut phases = Vec::new();
    let done = compend::calibrate::set::calibrate_set(
        displays,
        &mut rig.clone(),
        &dir.path().join("data"),
        &opts,
        &mut |phase, _, _| {
            if phases.last().is_none_or(|p: &String| p != phase) {
                phases.push(phase.to_string());
            }
        },
    )
    .unwrap();
    assert!(
        phases
            .iter()
            .any(|p| p.starts_with("projector 2/2: captures"))
    );
    assert_eq!(phases.last().map(String::as_str), Some("set verification"));
    let r = &done.record;
    let v = &r.verification;
    assert!(v.passed, "{v:?}");
    assert!(v.gain_db > 3.0, "{v:?}");
    let seam = v.seam.expect("a tiled set overlaps");
    assert!(seam.ratio() <= v.seam_limit, "{seam:?}");
    assert!(r.camera_gamma_spread < 0.2, "{}", r.camera_gamma_spread);
    // What the set showed is on disk for a person to look at; a file of someone else's there
    // stops the next calibration before it writes, and stays.
    assert!(dir.path().join("data/set/joint-001.png").is_file());
    std::fs::write(dir.path().join("data/set/notes.txt"), b"mine").unwrap();
    let again = compend::calibrate::set::calibrate_set(
        vec![rig.output(0).unwrap(), rig.output(1).unwrap()],
        &mut rig.clone(),
        &dir.path().join("data"),
        &opts,
        &mut |_, _, _| {},
    );
    let e = again.err().expect("refused").to_string();
    assert!(e.contains("notes.txt"), "{e}");
    assert_eq!(
        std::fs::read(dir.path().join("data/set/notes.txt")).unwrap(),
        b"mine"
    );
    // Each projector's field of view is its own picture.
    let iou = |a: &Mask<Camera>, b: &Mask<Camera>| {
        let both = a.data().iter().zip(b.data()).filter(|(x, y)| **x && **y);
        let any = a.data().iter().zip(b.data()).filter(|(x, y)| **x || **y);
        both.count() as f64 / any.count().max(1) as f64
    };
    for k in 0..2 {
        let fov = &done.model.models[k].fov;
        let truth = set.projectors()[k].lit_mask();
        let other = set.projectors()[1 - k].lit_mask();
        assert!(iou(fov, &truth) > 0.8, "projector {}", k + 1);
        assert!(iou(fov, &other) < 0.4, "projector {}", k + 1);
        assert!(done.model.models[k].meta.calibration.is_some());
    }
    // Installed, loaded back, compensated jointly.
    let out = dir.path().join("model");
    let installed = compend::calibrate::set::install_set(done, &out).unwrap();
    assert!(out.join("set.json").is_file() && out.join("projector-2/model.json").is_file());
    let loaded = SetModel::load(&out).unwrap();
    let (a, b) = (&loaded.meta, &installed.meta);
    assert_eq!((a.projectors, a.camera_size), (b.projectors, b.camera_size));
    let (a, b) = (
        a.calibration.as_ref().unwrap(),
        b.calibration.as_ref().unwrap(),
    );
    assert_eq!(
        (a.area, a.verification.passed),
        (b.area, b.verification.passed)
    );
    let joint = loaded.joint().unwrap();
    let desired = CamImage::filled(96, 72, [0.3, 0.3, 0.3]);
    let outs = joint.apply(&desired).unwrap();
    assert_eq!(outs.len(), 2);
    let e = compend::model::Model::load(&out).unwrap_err().to_string();
    assert!(e.contains("the model of a set of projectors"), "{e}");
    // Saving over it again is allowed (a set's model directory); over a folder that holds
    // something else it is not.
    loaded.save(&out).unwrap();
    let other = dir.path().join("other");
    std::fs::create_dir_all(&other).unwrap();
    std::fs::write(other.join("notes.txt"), b"mine").unwrap();
    let e = loaded.save(&other).unwrap_err().to_string();
    assert!(e.contains("notes.txt"), "{e}");
    assert_eq!(std::fs::read(other.join("notes.txt")).unwrap(), b"mine");
}
