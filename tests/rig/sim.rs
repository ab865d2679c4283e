//! The simulator and the virtual rig through the library: determinism, latency and drops,
//! self-occlusion, drift, and the FOV mask against the simulator's ground truth.

use super::*;
use compend::raster::ImageSize;

#[test]
fn same_seed_same_frames_other_seed_other_frames() {
    let a = tiny("textured-plane", 11);
    let b = tiny("textured-plane", 11);
    let c = tiny("textured-plane", 12);
    let img = on_canvas(&a, 1);
    let fa = a.capture(&img, 3).expect("capture");
    assert_eq!(
        fa,
        b.capture(&img, 3).expect("capture"),
        "same seed, same frame"
    );
    assert_ne!(
        fa,
        a.capture(&img, 4).expect("capture"),
        "next frame has fresh noise"
    );
    assert_ne!(
        fa,
        c.capture(&img, 3).expect("capture"),
        "other seed: other texture and noise"
    );
    // The noise-free part depends on the seed only through the texture: the white wall's does
    // not change with the seed, its noise does.
    let w1 = tiny("white-plane", 1);
    let w2 = tiny("white-plane", 2);
    let white = PrjImage::filled(PRJ.width, PRJ.height, [1.0; 3]);
    assert_eq!(
        w1.expected(&white).expect("render"),
        w2.expected(&white).expect("render")
    );
    assert_ne!(
        w1.capture(&white, 0).expect("capture"),
        w2.capture(&white, 0).expect("capture")
    );

    // The rig as devices: identical seeds give identical frame streams (images, numbers,
    // times), drops included.
    let stream = |seed: u64| {
        let scene = rig::builtin("curved")
            .expect("built-in")
            .with_resolution(CAM, PRJ);
        let mut prj = rig::VirtualRig::new(&scene, seed).expect("rig");
        let mut cam = prj.clone();
        let mut out = Vec::new();
        for k in 0..6 {
            prj.show(&on_canvas(&tiny("curved", seed), k))
                .expect("show");
            out.push(cam.grab().expect("grab"));
        }
        out
    };
    let s1 = stream(21);
    assert_eq!(s1, stream(21));
    assert_ne!(s1, stream(22));
}

#[test]
fn averaged_captures_scatter_less_around_the_noise_free_view() {
    // The noisiest built-in scene, so the noise is well above the 8-bit quantisation.
    let sim = tiny("defocus-noise", 5);
    let img = on_canvas(&sim, 2);
    let clean = sim.expected(&img).expect("render");
    let rms = |c: &CamImage| {
        let d = c.data().iter().zip(clean.data());
        (d.map(|(a, b)| ((a - b) as f64).powi(2)).sum::<f64>() / clean.data().len() as f64).sqrt()
    };
    assert_eq!(
        sim.capture_mean(&img, 40, 1).expect("mean"),
        sim.capture(&img, 40).expect("capture"),
        "one frame is a capture"
    );
    let one = rms(&sim.capture(&img, 40).expect("capture"));
    let four = rms(&sim.capture_mean(&img, 40, 4).expect("mean"));
    // Independent noise: the mean of 4 frames has about half the deviation (quantisation and
    // clipping keep it from exactly half).
    assert!(
        four < 0.7 * one,
        "4 frames: RMS {four:.4} from the noise-free view, 1 frame: {one:.4}"
    );
    // Scoring: frames of image k follow those of image k − 1 without overlap.
    let frames = rig::score::Frames {
        first: 100,
        average: 3,
    };
    assert_eq!(
        frames.capture(&sim, &img, 2).expect("capture"),
        sim.capture_mean(&img, 106, 3).expect("mean")
    );
}

#[test]
fn frames_lag_behind_the_projector_and_drops_skip_numbers() {
    let scene = rig::builtin("white-plane")
        .expect("built-in")
        .with_resolution(CAM, PRJ);
    let white = PrjImage::filled(PRJ.width, PRJ.height, [1.0; 3]);
    let lit = tiny("white-plane", 0).lit_mask();
    let is_white = |f: &compend::device::Frame| mean(&f.image, Some(&lit)) > 0.5;

    for delay in [0u32, 1, 3] {
        let mut prj = rig::VirtualRig::new(&scene, 4).expect("rig");
        prj.set_latency(rig::scene::Latency {
            fps: 30.0,
            delay_frames: delay,
            drop_rate: 0.0,
        })
        .expect("latency");
        let mut cam = prj.clone();
        assert_eq!(DisplaySink::size(&prj), PRJ);
        assert_eq!(FrameSource::size(&cam), CAM);
        // Settle on black, then switch to white.
        let mut last = None;
        for _ in 0..4 {
            let f = cam.grab().expect("grab");
            assert!(!is_white(&f));
            last = Some(f.seq);
        }
        prj.show(&white).expect("show");
        let frames: Vec<_> = (0..delay + 2).map(|_| cam.grab().expect("grab")).collect();
        for (k, f) in frames.iter().enumerate() {
            assert_eq!(
                Some(f.seq),
                last.map(|l| l + 1 + k as u64),
                "no drops: consecutive"
            );
            assert_eq!(
                is_white(f),
                k as u32 >= delay,
                "delay {delay}: frame {k} after the switch"
            );
            assert!(
                (f.timestamp.as_secs_f64() - f.seq as f64 / 30.0).abs() < 1e-9,
                "timestamp is the exposure time"
            );
        }
    }

    // Drops: sequence numbers keep increasing but jump, about as often as the rate says.
    let mut prj = rig::VirtualRig::new(&scene, 9).expect("rig");
    prj.set_latency(rig::scene::Latency {
        fps: 30.0,
        delay_frames: 1,
        drop_rate: 0.25,
    })
    .expect("latency");
    let mut cam = prj.clone();
    let seqs: Vec<u64> = (0..200).map(|_| cam.grab().expect("grab").seq).collect();
    let gaps = seqs.windows(2).filter(|w| w[1] > w[0] + 1).count();
    assert!(seqs.windows(2).all(|w| w[1] > w[0]));
    let dropped = seqs[199] - seqs[0] + 1 - 200;
    assert!(
        gaps > 0 && (30..100).contains(&dropped),
        "dropped {dropped} in {gaps} gaps"
    );
    // A frame shown after a drop still lags by the delay: the first frame after show is old.
    prj.show(&white).expect("show");
    assert!(!is_white(&cam.grab().expect("grab")));
    // Wrong sizes are refused.
    assert!(prj.show(&PrjImage::new(10, 10)).is_err());
}

/// On the wall clock the virtual camera makes a frame's picture as soon as it is asked for and
/// the exposure has started, then holds it until its delivery time, as a real camera's sensor
/// is read out while the frame travels: the time this machine takes to simulate a frame hides
/// in the camera's delay instead of adding to it. A setting changed while a frame waits for
/// its delivery therefore reaches the next frame, not that one.
#[test]
fn on_the_wall_clock_a_frame_is_made_before_its_delivery() {
    let scene = rig::builtin("white-plane")
        .expect("built-in")
        .with_resolution(CAM, PRJ);
    let rig = rig::VirtualRig::new(&scene, 5).expect("rig");
    let latency = |delay_frames| rig::scene::Latency {
        fps: 10.0,
        delay_frames,
        drop_rate: 0.0,
    };
    // White from the first exposure on (no delay yet, no clock yet), then 3 frames of delay
    // on the wall clock: frame 0 is delivered 0.3 s after the clock starts.
    rig.set_latency(latency(0)).expect("latency");
    let mut prj = rig.clone();
    prj.show(&PrjImage::filled(PRJ.width, PRJ.height, [1.0; 3]))
        .expect("show");
    rig.set_latency(latency(3)).expect("latency");
    let rig = rig.on_wall_clock();
    let started = std::time::Instant::now();
    let mut cam = rig.clone();
    let reader = std::thread::spawn(move || {
        let first = cam.grab().expect("grab");
        let at = started.elapsed();
        (first, at, cam.grab().expect("grab"))
    });
    // Halfway through frame 0's delay: a shorter exposure.
    std::thread::sleep(std::time::Duration::from_millis(150));
    let mut camera = rig.clone();
    camera.set_exposure(1.0 / 16.0).expect("exposure");
    let (first, at, second) = reader.join().expect("reader");
    assert_eq!((first.seq, second.seq), (0, 1));
    assert!(
        at >= std::time::Duration::from_millis(290),
        "frame 0 came after {at:?}, before its delivery time (0.3 s)"
    );
    let (a, b) = (mean(&first.image, None), mean(&second.image, None));
    assert!(
        a > 2.0 * b,
        "frame 0 was made before the exposure changed ({a:.3}), frame 1 after ({b:.3})"
    );
}

#[test]
fn step_scene_has_a_shadow_the_projector_cannot_reach() {
    let sim = tiny("step", 1);
    let shadow = sim.shadow_mask();
    let lit = sim.lit_mask();
    assert!(
        shadow.count() >= 40,
        "shadowed camera pixels: {}",
        shadow.count()
    );
    // No pixel is both; shadowed pixels have no projector coordinate.
    for i in 0..shadow.data().len() {
        assert!(!(shadow.data()[i] && lit.data()[i]));
        if shadow.data()[i] {
            assert!(sim.projector_coords()[i][0].is_nan());
        }
    }
    // Under full white the shadow stays as dark as under black; lit pixels brighten.
    let white = sim
        .expected(&PrjImage::filled(PRJ.width, PRJ.height, [1.0; 3]))
        .expect("render");
    let black = sim
        .expected(&PrjImage::new(PRJ.width, PRJ.height))
        .expect("render");
    let gain = |m: &Mask<Camera>| mean(&white, Some(m)) - mean(&black, Some(m));
    assert!(
        gain(&shadow) < 0.01,
        "shadow brightens by {}",
        gain(&shadow)
    );
    assert!(gain(&lit) > 0.4, "lit area brightens by {}", gain(&lit));
    // The other scenes have (almost) no shadow.
    assert_eq!(tiny("white-plane", 1).shadow_mask().count(), 0);
}

#[test]
fn drift_moves_the_projector_by_about_the_given_shift() {
    // Full projector resolution so the shift is the scene's 1.5 px right, 1 px up.
    let scene = rig::builtin("drift")
        .expect("built-in")
        .with_resolution(CAM, ImageSize::new(800, 600));
    let before = Simulator::new(&scene, 1, Phase::Calibration).expect("builds");
    let after = Simulator::new(&scene, 1, Phase::AfterDrift).expect("builds");
    let (mut dx, mut dy, mut n) = (0.0f64, 0.0f64, 0usize);
    for (a, b) in before
        .projector_coords()
        .iter()
        .zip(after.projector_coords())
    {
        if a[0].is_finite() && b[0].is_finite() {
            dx += (a[0] - b[0]) as f64;
            dy += (a[1] - b[1]) as f64;
            n += 1;
        }
    }
    // The image moved right and up on the surface (shift [1.5, -1]), so a fixed surface point
    // is now lit by a projector pixel that far to the left and further down.
    let (dx, dy) = (dx / n as f64, dy / n as f64);
    assert!(
        (dx - 1.5).abs() < 0.4 && (dy + 1.0).abs() < 0.4,
        "mean shift {dx:.3}, {dy:.3}"
    );
    // The rig switches pose on request; a scene without drift is unaffected.
    let rig = rig::VirtualRig::new(&scene, 1).expect("rig");
    rig.set_phase(Phase::AfterDrift).expect("drift");
    assert_eq!(rig.simulator().phase(), Phase::AfterDrift);
    let plain = rig::builtin("curved")
        .expect("built-in")
        .with_resolution(CAM, PRJ);
    let a = Simulator::new(&plain, 1, Phase::Calibration).expect("builds");
    let b = Simulator::new(&plain, 1, Phase::AfterDrift).expect("builds");
    let img = on_canvas(&a, 0);
    assert_eq!(
        a.expected(&img).expect("render"),
        b.expected(&img).expect("render")
    );
}

/// The FOV mask found from the black and white captures (`fov::fov_mask`) agrees with the
/// simulator's ground truth on every scene, the dark texture and the shadowed step included
/// (the dark scene is the case the FOV algorithm is built for: see `compend::fov`).
#[test]
fn fov_from_captures_matches_the_truth() {
    for name in rig::BUILTIN {
        let scene = rig::builtin(name)
            .expect("built-in")
            .with_resolution(ImageSize::new(160, 120), ImageSize::new(200, 150));
        let sim = Simulator::new(&scene, 4, Phase::Calibration).expect("builds");
        let ImageSize {
            width: pw,
            height: ph,
        } = sim.projector_size();
        let black = sim.capture(&PrjImage::new(pw, ph), 1).expect("capture");
        let white = sim
            .capture(&PrjImage::filled(pw, ph, [1.0; 3]), 2)
            .expect("capture");
        let found = compend::fov::fov_mask(&black, &white, name)
            .expect("a FOV")
            .mask;
        let truth = sim.lit_mask();
        let both = found
            .data()
            .iter()
            .zip(truth.data())
            .filter(|(a, b)| **a && **b)
            .count();
        let either = found
            .data()
            .iter()
            .zip(truth.data())
            .filter(|(a, b)| **a || **b)
            .count();
        let iou = both as f64 / either as f64;
        eprintln!(
            "{name}: FOV IoU {iou:.4} (found {}, true {})",
            found.count(),
            truth.count()
        );
        assert!(iou > 0.95, "{name}: IoU {iou:.3}");
    }
}
