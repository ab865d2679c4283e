//! The camera without hardware: [`compend::camera::Camera`] over a scripted fake device
//! (format negotiation, corrupt frames counted and skipped, timeouts, an unplug survived and
//! reconnected with format and controls applied again, the calibration lock and its report),
//! and `compend cameras` through the real binary on a machine with or without cameras.
//! Tests that need a real V4L2 camera are ignored; their doc comments say how to run them.

mod fake;

use std::collections::BTreeMap;
use std::path::Path;
use std::time::{Duration, Instant};

use compend::calibrate::sync::{Capturer, MAX_RECONNECTS, SyncSettings};
use compend::camera::controls::{Outcome, Role, cid};
use compend::camera::format::v4l2_codes::QUANTIZATION_FULL_RANGE;
use compend::camera::{
    Camera, LockSettings, Matrix, OpenOptions, PixelFormat, PowerLine, Range, Reconnect,
};
use compend::device::{DisplaySink, FrameSource};
use compend::raster::{ImageSize, PrjImage};
use compend::record::Latency;

use crate::common::{assert_code, compend, stderr, stdout};
use fake::{Event, FakeOpener, Shared, offer, script};

const DEV: &str = "/dev/video-fake";

fn open(s: &Shared, size: (usize, usize)) -> Camera<FakeOpener> {
    let options = OpenOptions {
        size: Some(ImageSize::from(size)),
        timeout: Duration::from_millis(300),
        reconnect: Reconnect {
            attempts: 4,
            first_delay: Duration::ZERO,
            max_delay: Duration::ZERO,
        },
        ..OpenOptions::default()
    };
    Camera::open_with(FakeOpener(s.clone()), Path::new(DEV), options).unwrap()
}

/// An 8x4 YUYV frame of one gray level (limited range: 16 black, 235 white).
fn yuyv(level: u8) -> Vec<u8> {
    [level, 128, level, 128].repeat(4 * 4)
}

fn frame(data: Vec<u8>, seq: u32) -> Event {
    Event::Frame {
        data,
        seq,
        error: false,
    }
}

/// A JPEG of `w`×`h` pixels of one colour.
fn jpeg(w: u32, h: u32, rgb: [u8; 3]) -> Vec<u8> {
    let img = image::RgbImage::from_pixel(w, h, image::Rgb(rgb));
    let mut out = Vec::new();
    image::codecs::jpeg::JpegEncoder::new_with_quality(&mut out, 95)
        .encode_image(&img)
        .unwrap();
    out
}

#[test]
fn negotiation_prefers_uncompressed_and_decodes_with_the_drivers_colorimetry() {
    let s = script();
    let mut cam = open(&s, (8, 4));
    assert_eq!(cam.active_format().format, PixelFormat::Yuyv);
    // The driver says nothing: SD size, BT.601, limited range.
    assert_eq!(cam.ycbcr().matrix, Matrix::Bt601);
    assert_eq!(cam.ycbcr().range, Range::Limited);
    assert!(cam.describe().contains("8x4 YUYV, BT.601 limited range"));
    s.borrow_mut().events.push_back(frame(yuyv(235), 7));
    let f = cam.grab().unwrap();
    assert_eq!(f.image.size(), ImageSize::new(8, 4));
    assert_eq!(f.image.get(3, 2), [1.0, 1.0, 1.0]);
    assert_eq!(f.seq, 7);
    // The driver says full range: the same bytes are a light gray, not white.
    let s = script();
    s.borrow_mut().colorimetry = (0, 0, QUANTIZATION_FULL_RANGE);
    let mut cam = open(&s, (8, 4));
    s.borrow_mut().events.push_back(frame(yuyv(235), 1));
    assert_eq!(cam.grab().unwrap().image.get(0, 0), [235.0 / 255.0; 3]);
    // Only MJPEG has 16x8.
    let s = script();
    let mut cam = open(&s, (16, 8));
    assert_eq!(cam.active_format().format, PixelFormat::Mjpeg);
    s.borrow_mut()
        .events
        .push_back(frame(jpeg(16, 8, [200, 30, 30]), 1));
    let px = cam.grab().unwrap().image.get(5, 5);
    assert!(px[0] > 0.7 && px[1] < 0.2, "{px:?}");
}

#[test]
fn an_unsupported_format_list_is_an_input_error_listing_the_offers() {
    let s = script();
    s.borrow_mut().formats = vec![offer(b"H264", &[(1920, 1080)]), offer(b"GREY", &[(8, 4)])];
    let e = Camera::open_with(FakeOpener(s), Path::new(DEV), OpenOptions::default())
        .err()
        .unwrap();
    let msg = e.to_string();
    assert_eq!(e.exit_code(), 2, "{msg}");
    assert!(
        msg.contains(DEV) && msg.contains("H264") && msg.contains("GREY"),
        "{msg}"
    );
}

#[test]
fn corrupt_frames_are_counted_and_skipped_never_returned() {
    let s = script();
    let mut cam = open(&s, (8, 4));
    {
        let mut s = s.borrow_mut();
        s.events.push_back(Event::Frame {
            data: yuyv(100),
            seq: 1,
            error: true,
        });
        s.events.push_back(frame(yuyv(100)[..40].to_vec(), 2)); // cut short
        s.events.push_back(frame(Vec::new(), 3)); // empty
        s.events.push_back(frame(yuyv(16), 4));
    }
    let f = cam.grab().unwrap();
    assert_eq!((f.seq, f.image.get(0, 0)), (4, [0.0; 3]));
    assert_eq!(cam.corrupt_frames(), 3);
    // MJPEG: a truncated frame and garbage are skipped too.
    let s = script();
    let mut cam = open(&s, (16, 8));
    let good = jpeg(16, 8, [0, 0, 255]);
    {
        let mut s = s.borrow_mut();
        s.events
            .push_back(frame(good[..good.len() - 30].to_vec(), 1));
        s.events
            .push_back(frame(vec![0xFF, 0xD8, 1, 2, 3, 0xFF, 0xD9], 2));
        s.events.push_back(frame(jpeg(8, 4, [0, 0, 255]), 3)); // wrong size
        s.events.push_back(frame(good, 4));
    }
    assert_eq!(cam.grab().unwrap().seq, 4);
    assert_eq!(cam.corrupt_frames(), 3);
}

#[test]
fn a_grab_times_out_instead_of_hanging() {
    let s = script();
    let mut cam = open(&s, (8, 4));
    s.borrow_mut().events.push_back(Event::Timeout);
    let start = Instant::now();
    let e = cam.grab().unwrap_err();
    assert!(start.elapsed() < Duration::from_secs(2));
    let msg = e.to_string();
    assert!(
        msg.contains(DEV) && msg.contains("no good frame within 0.3 s"),
        "{msg}"
    );
    // Only corrupt frames until the deadline: the error says how many were skipped.
    for seq in 0..3 {
        s.borrow_mut().events.push_back(Event::Frame {
            data: yuyv(1),
            seq,
            error: true,
        });
    }
    let msg = cam.grab().unwrap_err().to_string();
    assert!(msg.contains("3 corrupt frames skipped"), "{msg}");
    // The camera still works afterwards.
    s.borrow_mut().events.push_back(frame(yuyv(16), 9));
    assert_eq!(cam.grab().unwrap().seq, 9);
}

#[test]
fn an_unplugged_camera_is_survived_and_reconnect_applies_format_and_lock_again() {
    let s = script();
    let mut cam = open(&s, (8, 4));
    // Before the lock the exposure is automatic: calibration cannot range it.
    assert!(FrameSource::exposure(&cam).is_none());
    assert!(FrameSource::set_exposure(&mut cam, 50.0).is_err());
    let settings = LockSettings {
        exposure: Some(100),
        ..LockSettings::default()
    };
    let report = cam.lock_for_calibration(&settings).unwrap();
    assert_eq!(report.exposure(), Some(100));
    s.borrow_mut().events.push_back(frame(yuyv(16), 41));
    assert_eq!(cam.grab().unwrap().seq, 41);
    s.borrow_mut().events.push_back(Event::Gone);
    let e = cam.grab().unwrap_err();
    assert!(
        e.to_string().contains(DEV) && e.to_string().contains("gone"),
        "{e}"
    );
    assert!(!cam.is_connected());
    // Grabbing again is the same error, not a panic or a hang.
    assert!(cam.grab().is_err());
    // The device is back after two failed opens.
    s.borrow_mut().failing_opens = 2;
    let opens_before = s.borrow().opens;
    cam.reconnect().unwrap();
    assert_eq!(s.borrow().opens, opens_before + 3);
    assert!(cam.is_connected());
    assert_eq!(cam.reconnects(), 1);
    assert_eq!(cam.active_format().format, PixelFormat::Yuyv);
    assert_eq!(FrameSource::size(&cam), ImageSize::new(8, 4));
    // The new device holds the lock: manual exposure at 100, auto white balance off.
    let now: BTreeMap<u32, Option<i64>> = cam
        .controls()
        .unwrap()
        .into_iter()
        .map(|c| (c.id, c.value))
        .collect();
    assert_eq!(now[&cid::EXPOSURE_AUTO], Some(1));
    assert_eq!(now[&cid::EXPOSURE_ABSOLUTE], Some(100));
    assert_eq!(now[&cid::AUTO_WHITE_BALANCE], Some(0));
    assert!(cam.lock_report().is_some_and(|r| r.exposure() == Some(100)));
    // Sequence numbers keep increasing although the driver starts again at 0.
    s.borrow_mut().events.push_back(frame(yuyv(16), 0));
    assert_eq!(cam.grab().unwrap().seq, 42);
    // An exposure set later (through the frame source, as calibration's exposure ranging
    // does) is kept for the next reconnect too.
    let range = FrameSource::exposure(&cam).unwrap();
    assert_eq!((range.value, range.min, range.max), (100.0, 3.0, 2047.0));
    assert_eq!(FrameSource::set_exposure(&mut cam, 299.6).unwrap(), 300.0);
    assert_eq!(FrameSource::exposure(&cam).map(|r| r.value), Some(300.0));
    cam.reconnect().unwrap();
    let exposure = cam
        .controls()
        .unwrap()
        .into_iter()
        .find(|c| c.id == cid::EXPOSURE_ABSOLUTE)
        .and_then(|c| c.value);
    assert_eq!(exposure, Some(300));
    assert_eq!(FrameSource::exposure(&cam).map(|r| r.value), Some(300.0));
}

/// A projector that shows anything it is given (the fake camera's frames are scripted).
struct Wall;

impl DisplaySink for Wall {
    fn size(&self) -> ImageSize {
        ImageSize::new(4, 4)
    }
    fn show(&mut self, _frame: &PrjImage) -> compend::Result<()> {
        Ok(())
    }
}

fn capturer_settings() -> (Latency, SyncSettings) {
    let latency = Latency {
        trials: vec![0],
        settle_frames: 0,
        black_level: 0.0,
        white_level: 1.0,
    };
    let sync = SyncSettings {
        average: 2,
        retakes: 0,
        ..SyncSettings::default()
    };
    (latency, sync)
}

#[test]
fn a_capture_survives_the_camera_going_away_and_is_taken_again_after_it_is_back() {
    let s = script();
    let mut cam = open(&s, (8, 4));
    let (latency, sync) = capturer_settings();
    let mut wall = Wall;
    let pattern = PrjImage::filled(4, 4, [1.0; 3]);
    // The camera goes away after the first of the two averaged frames; the first reopen fails.
    {
        let mut script = s.borrow_mut();
        script.events.push_back(frame(yuyv(16), 7));
        script.events.push_back(Event::Gone);
        script.failing_opens = 1;
        script.events.push_back(frame(yuyv(235), 0));
        script.events.push_back(frame(yuyv(235), 1));
    }
    let mut cap = Capturer::new(&mut wall, &mut cam, &latency, sync);
    let img = cap.capture(&pattern, false).unwrap();
    assert_eq!(cap.reconnects, 1);
    // Both averaged frames come from after the reconnect (white), none from before (black).
    assert!(
        img.data().iter().all(|&v| v > 0.95),
        "{:?}",
        &img.data()[..3]
    );
    drop(cap);
    assert!(cam.is_connected());
    assert_eq!(cam.reconnects(), 1);

    // A camera that stays away: the capture fails with the reason and the device, no hang.
    s.borrow_mut().events.push_back(Event::Gone);
    s.borrow_mut().failing_opens = 100;
    let mut wall = Wall;
    let mut cap = Capturer::new(&mut wall, &mut cam, &latency, sync);
    let msg = cap.capture(&pattern, false).unwrap_err().to_string();
    assert!(
        msg.contains(DEV) && msg.contains("gone") && msg.contains("could not reopen"),
        "{msg}"
    );
    assert_eq!(cap.reconnects, 0);
}

#[test]
fn a_camera_that_keeps_going_away_fails_the_capture_after_a_few_reconnects() {
    let s = script();
    let mut cam = open(&s, (8, 4));
    let (latency, sync) = capturer_settings();
    let mut wall = Wall;
    for _ in 0..=MAX_RECONNECTS {
        s.borrow_mut().events.push_back(Event::Gone);
    }
    let mut cap = Capturer::new(&mut wall, &mut cam, &latency, sync);
    let msg = cap
        .capture(&PrjImage::filled(4, 4, [0.5; 3]), false)
        .unwrap_err()
        .to_string();
    assert_eq!(cap.reconnects, MAX_RECONNECTS);
    assert!(msg.contains("gone"), "{msg}");
    // A timeout is not a reason to reopen: the camera is still there.
    let mut cam = open(&script(), (8, 4));
    let mut wall = Wall;
    let mut cap = Capturer::new(&mut wall, &mut cam, &latency, sync);
    let msg = cap
        .capture(&PrjImage::filled(4, 4, [0.5; 3]), false)
        .unwrap_err()
        .to_string();
    assert_eq!(cap.reconnects, 0);
    assert!(msg.contains("no good frame"), "{msg}");
}

#[test]
fn reconnect_gives_up_with_an_error_naming_the_device() {
    let s = script();
    let mut cam = open(&s, (8, 4));
    s.borrow_mut().failing_opens = 100;
    let e = cam.reconnect().unwrap_err();
    let msg = e.to_string();
    assert!(
        msg.contains(DEV) && msg.contains("4 attempts") && msg.contains("plugged in"),
        "{msg}"
    );
    assert!(!cam.is_connected());
    assert!(cam.grab().is_err());
}

#[test]
fn the_lock_writes_exposure_after_manual_and_again_last_and_reports_each_control() {
    let s = script();
    s.borrow_mut().gain_resets_exposure = true;
    s.borrow_mut().refused = vec![cid::BACKLIGHT_COMPENSATION];
    let mut cam = open(&s, (8, 4));
    let settings = LockSettings {
        exposure: Some(80),
        gain: Some(400), // beyond the range: clamped to 255
        white_balance: Some(5004),
        focus: Some(10),
        backlight_compensation: None,
        power_line: Some(PowerLine::Hz50),
    };
    let r = cam.lock_for_calibration(&settings).unwrap();
    let get = |role| r.get(role).unwrap();
    assert_eq!(get(Role::ExposureAuto).accepted, Some(1));
    assert_eq!(
        (get(Role::Exposure).requested, get(Role::Exposure).accepted),
        (Some(80), Some(80))
    );
    assert_eq!(get(Role::Exposure).outcome, Outcome::Accepted);
    assert_eq!(get(Role::Gain).accepted, Some(255));
    assert_eq!(get(Role::Gain).outcome, Outcome::Adjusted);
    assert_eq!(get(Role::WhiteBalance).accepted, Some(5000));
    assert_eq!(get(Role::PowerLine).accepted, Some(1));
    assert_eq!(get(Role::Focus).outcome, Outcome::Absent);
    assert_eq!(get(Role::FocusAuto).outcome, Outcome::Absent);
    assert!(matches!(
        get(Role::BacklightCompensation).outcome,
        Outcome::Rejected(_)
    ));
    assert!(r.exposure_is_manual());
    // The exposure was written after the switch to manual and once more at the very end
    // (here the gain write reset it in between).
    let writes: Vec<u32> = s.borrow().writes.iter().map(|w| w.1).collect();
    let manual = writes
        .iter()
        .position(|&id| id == cid::EXPOSURE_AUTO)
        .unwrap();
    let first = writes
        .iter()
        .position(|&id| id == cid::EXPOSURE_ABSOLUTE)
        .unwrap();
    assert!(manual < first);
    assert_eq!(writes.last(), Some(&cid::EXPOSURE_ABSOLUTE));
    let lines = r.lines().join("\n");
    assert!(
        lines.contains("exposure (100 µs): requested 80, holds 80"),
        "{lines}"
    );
    assert!(lines.contains("focus: the camera has none"), "{lines}");
}

#[test]
fn the_lock_keeps_what_the_automatic_modes_chose_when_given_no_values() {
    let s = script();
    let mut cam = open(&s, (8, 4));
    let r = cam.lock_for_calibration(&LockSettings::default()).unwrap();
    // The camera's automatic exposure had settled on 250 (100 µs units) and 4600 K.
    assert_eq!(r.exposure(), Some(250));
    assert_eq!(r.get(Role::WhiteBalance).unwrap().accepted, Some(4600));
    assert_eq!(r.get(Role::AutoWhiteBalance).unwrap().accepted, Some(0));
    assert_eq!(
        r.get(Role::BacklightCompensation).unwrap().accepted,
        Some(0)
    );
    // Power line: kept as it was (60 Hz).
    assert_eq!(r.get(Role::PowerLine).unwrap().accepted, Some(2));
    assert!(r.problems().is_empty(), "{:?}", r.problems());
}

/// Whether this machine has any /dev/videoN.
fn has_video_nodes() -> bool {
    std::fs::read_dir("/dev").is_ok_and(|d| {
        d.flatten().any(|e| {
            e.file_name()
                .to_str()
                .and_then(|n| n.strip_prefix("video"))
                .is_some_and(|n| n.parse::<u32>().is_ok())
        })
    })
}

#[test]
fn cameras_lists_devices_or_says_there_is_none() {
    let o = compend(&["cameras"]);
    assert_code(&o, 0);
    let j = compend(&["cameras", "--json"]);
    assert_code(&j, 0);
    let list: serde_json::Value = serde_json::from_str(&stdout(&j)).unwrap();
    assert!(list.is_array());
    if !has_video_nodes() {
        assert_eq!(stdout(&o), "no camera found (no /dev/video* device)\n");
        assert_eq!(list.as_array().map(Vec::len), Some(0));
    }
}

#[test]
fn cameras_refuses_a_path_that_is_not_a_camera_with_exit_2() {
    for (path, says) in [
        ("/etc/passwd", "not a camera"),
        ("/dev/null", "not a camera"),
        ("/dev/no-such-video-device", "missing"),
    ] {
        let o = compend(&["cameras", "--device", path]);
        assert_code(&o, 2);
        let err = stderr(&o);
        assert!(err.contains(path) && err.contains(says), "{path}: {err}");
    }
    // A camera named by an index or a name that no camera found has: exit 2, and what to give.
    for name in ["4096", "no-such-camera-name"] {
        for args in [
            vec!["cameras", "--device", name],
            vec!["calibrate", "--camera", name, "--out", "/nonexistent/model"],
        ] {
            let o = compend(&args);
            assert_code(&o, 2);
            let err = stderr(&o);
            assert!(
                err.contains(&format!("camera \"{name}\"")) && err.contains("compend cameras"),
                "{args:?}: {err}"
            );
        }
    }
}

/// By hand, with a UVC camera at /dev/video0 (override with `COMPEND_TEST_CAMERA`):
/// `cargo test --test integration camera::real -- --ignored --nocapture`. It grabs frames,
/// locks the controls and prints the report; then unplug the camera when told and plug it
/// back in: the grab fails with "gone", and the reconnect (up to 30 s) succeeds with the same
/// exposure. Also check `compend cameras` lists the camera's formats and controls, and that
/// `compend play --model MODEL --source v4l2:/dev/video0 --rig virtual --frames 30` runs.
#[test]
#[ignore = "needs a V4L2 camera"]
fn real_camera_locks_survives_an_unplug_and_reconnects() {
    let path = std::env::var("COMPEND_TEST_CAMERA").unwrap_or_else(|_| "/dev/video0".into());
    let options = OpenOptions {
        reconnect: Reconnect {
            attempts: 30,
            first_delay: Duration::from_secs(1),
            max_delay: Duration::from_secs(1),
        },
        ..OpenOptions::default()
    };
    let mut cam = Camera::open_with(compend::camera::V4l2, Path::new(&path), options).unwrap();
    println!("{}", cam.describe());
    let report = cam.lock_for_calibration(&LockSettings::default()).unwrap();
    println!("{}", report.lines().join("\n"));
    let a = cam.grab().unwrap();
    let b = cam.grab().unwrap();
    assert!(b.seq > a.seq && b.timestamp >= a.timestamp);
    println!("unplug the camera now");
    while cam.grab().is_ok() {}
    assert!(!cam.is_connected());
    println!("plug it back in");
    cam.reconnect().unwrap();
    let again = cam.lock_report().and_then(|r| r.exposure());
    assert_eq!(again, report.exposure());
    assert!(cam.grab().unwrap().seq > b.seq);
}
