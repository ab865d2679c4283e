//! Media through GStreamer: films made by GStreamer in the test (never committed) played on the
//! virtual rig with their frames counted, compensated frames written to a file that decodes
//! back with the same count, `gst:` pipelines, and bad media refused with words and exit 2.

use std::path::Path;
use std::time::Duration;

use gstreamer as gst;
use gstreamer::prelude::*;

use crate::common::{assert_code, compend, gpu, stderr};
use crate::play::{count, tiny_model};

/// Runs a GStreamer pipeline description to its end (a minute at most).
fn run_pipeline(desc: &str) {
    gst::init().unwrap();
    let p = gst::parse::launch(desc)
        .unwrap_or_else(|e| panic!("{desc}: {e}"))
        .downcast::<gst::Pipeline>()
        .unwrap();
    p.set_state(gst::State::Playing).unwrap();
    let bus = p.bus().unwrap();
    let msg = bus
        .timed_pop_filtered(
            gst::ClockTime::from_seconds(60),
            &[gst::MessageType::Eos, gst::MessageType::Error],
        )
        .expect("the pipeline ends within a minute");
    if let gst::MessageView::Error(e) = msg.view() {
        panic!("{desc}: {} ({:?})", e.error(), e.debug());
    }
    p.set_state(gst::State::Null).unwrap();
}

/// An MP4 film of `frames` frames of `w`×`h` at 30 fps (H.264, OpenH264), with AAC sound of
/// the same length when `sound`.
pub fn make_film(path: &Path, frames: u32, w: u32, h: u32, sound: bool) {
    let loc = path.to_str().unwrap();
    let mut desc = format!(
        "videotestsrc num-buffers={frames} pattern=ball ! \
         video/x-raw,width={w},height={h},framerate=30/1 ! videoconvert ! \
         openh264enc ! h264parse ! mp4mux name=mux ! filesink location={loc}"
    );
    if sound {
        // 1470 samples at 44.1 kHz: one buffer per video frame.
        desc.push_str(&format!(
            " audiotestsrc num-buffers={frames} samplesperbuffer=1470 ! \
             audio/x-raw,rate=44100,channels=2 ! audioconvert ! avenc_aac ! aacparse ! mux."
        ));
    }
    run_pipeline(&desc);
}

/// The frames a video file decodes to, counted by GStreamer alone.
pub fn decoded_frames(path: &Path) -> u64 {
    gst::init().unwrap();
    let desc = format!(
        "filesrc location={} ! decodebin ! videoconvert ! appsink name=s sync=false",
        path.to_str().unwrap()
    );
    let p = gst::parse::launch(&desc)
        .unwrap()
        .downcast::<gst::Pipeline>()
        .unwrap();
    let sink = p
        .by_name("s")
        .unwrap()
        .downcast::<gstreamer_app::AppSink>()
        .unwrap();
    p.set_state(gst::State::Playing).unwrap();
    let mut n = 0;
    while sink
        .try_pull_sample(gst::ClockTime::from_seconds(20))
        .is_some()
    {
        n += 1;
    }
    assert!(sink.is_eos(), "{}: decoding stalled", path.display());
    p.set_state(gst::State::Null).unwrap();
    n
}

fn play_json(args: &[&str]) -> (std::process::Output, Option<serde_json::Value>) {
    let mut all = vec!["play"];
    all.extend_from_slice(args);
    let o = compend(&all);
    let v = (o.status.code() == Some(0))
        .then(|| serde_json::from_slice(&o.stdout).expect("--json prints one object"));
    (o, v)
}

#[test]
fn a_film_plays_on_the_virtual_rig_and_renders_to_a_file() {
    if gpu().is_none() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let model = tiny_model(dir.path());
    let m = model.to_str().unwrap();
    let film = dir.path().join("film.mp4");
    make_film(&film, 12, 64, 48, true);

    // Offline: every frame of the film shown once, seen by the rig's camera, and written to
    // a compensated file that decodes back to as many frames.
    let views = dir.path().join("views");
    let rendered = dir.path().join("out.mp4");
    let to = format!("file:{}", rendered.display());
    let (o, v) = play_json(&[
        "--model",
        m,
        "--source",
        film.to_str().unwrap(),
        "--rig",
        "virtual:textured-plane",
        "--pace",
        "source",
        "--out",
        views.to_str().unwrap(),
        "--to",
        &to,
        "--json",
    ]);
    assert_code(&o, 0);
    let v = v.unwrap();
    eprintln!("{v}");
    assert_eq!(count(&v, "shown"), 12);
    assert_eq!(count(&v, "camera_views"), 12);
    assert_eq!(count(&v, "output_frames"), 12);
    assert_eq!(v["media"]["frames"], 12);
    assert_eq!(v["media"]["size"], serde_json::json!([64, 48]));
    assert!((v["media"]["fps"].as_f64().unwrap() - 30.0).abs() < 1e-6);
    assert!(views.join("cam_000012.png").is_file());
    assert_eq!(decoded_frames(&rendered), 12);
    // The film's own timing: 12 frames at 30 fps.
    let probe = compend::source::media::probe(
        &compend::source::MediaSpec::File(rendered.clone()),
        Duration::from_secs(10),
    )
    .unwrap();
    assert!((probe.fps.unwrap() - 30.0).abs() < 1e-3, "{probe:?}");
    // Its frames are the projector canvas (the rig's projector, 100x75, one black row added
    // for the encoder's even sides), not the film's size.
    assert_eq!(probe.size, Some((100, 76)));
    // Never over a file: the same command again is refused, the first file kept.
    let before = std::fs::metadata(&rendered).unwrap().len();
    let (o, _) = play_json(&[
        "--model",
        m,
        "--source",
        film.to_str().unwrap(),
        "--rig",
        "virtual:textured-plane",
        "--pace",
        "source",
        "--to",
        &to,
    ]);
    assert_code(&o, 2);
    assert!(stderr(&o).contains("already there"), "{}", stderr(&o));
    assert_eq!(std::fs::metadata(&rendered).unwrap().len(), before);

    // `compensate` of a film: a compensated film at the projector's size, frame for frame.
    let compensated = dir.path().join("compensated.mkv");
    let o = compend(&[
        "compensate",
        "--model",
        m,
        "--input",
        film.to_str().unwrap(),
        "--out",
        compensated.to_str().unwrap(),
        "--projector",
        "120x90",
    ]);
    assert_code(&o, 0);
    assert!(stderr(&o).contains("real time"), "{}", stderr(&o));
    assert_eq!(decoded_frames(&compensated), 12);
    // A model trained on recorded data records no canvas: the projector's size is asked for.
    let again = dir.path().join("again.mp4");
    let o = compend(&[
        "compensate",
        "--model",
        m,
        "--input",
        film.to_str().unwrap(),
        "--out",
        again.to_str().unwrap(),
    ]);
    assert_code(&o, 2);
    assert!(stderr(&o).contains("--projector"), "{}", stderr(&o));
    assert!(!again.exists());

    // Live, at the film's pace on a 60 Hz rig: its 12 frames over about 0.4 s, none lost by
    // the pipeline, its sound played (to a fake sink here) and delayed by the measured latency.
    let (o, v) = play_json(&[
        "--model",
        m,
        "--source",
        film.to_str().unwrap(),
        "--rig",
        "virtual:textured-plane",
        "--audio",
        "fakesink sync=true",
        "--json",
    ]);
    assert_code(&o, 0);
    let v = v.unwrap();
    eprintln!("{v}");
    assert_eq!(count(&v, "received"), 12);
    assert_eq!(count(&v, "shown") + count(&v, "dropped_source"), 12);
    assert_eq!(v["media"]["audio"], true);
    assert!(
        v["seconds"].as_f64().unwrap() >= 0.3,
        "12 frames at 30 fps take 0.4 s: {v}"
    );
    assert!(v["latency_ms_mean"].as_f64().unwrap() > 0.0);
    assert!(v["media"]["audio_delay_ms"].as_f64().unwrap() > 0.0, "{v}");
}

#[test]
fn gst_pipelines_play_and_bad_media_is_refused_in_words() {
    if gpu().is_none() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let model = tiny_model(dir.path());
    let m = model.to_str().unwrap();
    let rig = ["--rig", "virtual:textured-plane", "--pace", "source"];
    let play = |source: &str| {
        let mut args = vec!["--model", m, "--source", source, "--json"];
        args.extend_from_slice(&rig);
        play_json(&args)
    };

    // Any pipeline, ending in compend's sink.
    let (o, v) = play("gst:videotestsrc num-buffers=5 ! video/x-raw,width=40,height=30");
    assert_code(&o, 0);
    assert_eq!(count(&v.unwrap(), "shown"), 5);

    let words = |source: &str, expect: &str| {
        let (o, _) = play(source);
        assert_code(&o, 2);
        let e = stderr(&o);
        assert!(e.contains(expect), "{source}: {e}");
        assert!(!e.contains("gst_"), "no GStreamer debug string alone: {e}");
    };
    words(
        "gst:nosuchsrc ! videoconvert",
        "no GStreamer element \"nosuchsrc\"",
    );
    words(dir.path().join("missing.mp4").to_str().unwrap(), "missing");
    let text = dir.path().join("notes.mp4");
    std::fs::write(&text, "these are notes, not a film\n".repeat(50)).unwrap();
    words(text.to_str().unwrap(), "not a media file");
    let empty = dir.path().join("empty.mkv");
    std::fs::write(&empty, "").unwrap();
    words(&format!("file:{}", empty.display()), "empty");
    // A truncated film: what decodes plays, or it is refused in words; never a crash.
    let film = dir.path().join("film.mp4");
    make_film(&film, 30, 64, 48, false);
    let bytes = std::fs::read(&film).unwrap();
    let cut = dir.path().join("cut.mp4");
    std::fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap();
    let (o, _) = play(cut.to_str().unwrap());
    assert!(
        matches!(o.status.code(), Some(0) | Some(2)),
        "{}",
        stderr(&o)
    );
    // The demuxer's error is read while the film prerolls: the reason, not a timeout.
    assert!(!stderr(&o).contains("not ready after"), "{}", stderr(&o));
    // A codec no installed plugin decodes (the H.264 decoders taken out of the registry's
    // choice): named, with the Debian package that decodes it.
    let o = crate::common::output_within(
        std::process::Command::new(env!("CARGO_BIN_EXE_compend"))
            .args(["play", "--model", m, "--source", film.to_str().unwrap()])
            .args(rig)
            .env(
                "GST_PLUGIN_FEATURE_RANK",
                "avdec_h264:NONE,openh264dec:NONE",
            ),
    );
    assert_code(&o, 2);
    let e = stderr(&o);
    assert!(
        e.contains("H.264") && e.contains("gstreamer1.0-libav"),
        "{e}"
    );
    // Outputs: one projector takes one; an unknown element or an ending compend does not
    // write, before any frame.
    let (o, _) = play_json(&[
        "--model",
        m,
        "--source",
        film.to_str().unwrap(),
        "--rig",
        "virtual:textured-plane",
        "--to",
        "gst:fakesink",
        "--to",
        "gst:fakesink",
    ]);
    assert_code(&o, 2);
    assert!(
        stderr(&o).contains("--to given 2 times: one projector's frames go to one output"),
        "{}",
        stderr(&o)
    );
    let (o, _) = play_json(&[
        "--model",
        m,
        "--source",
        film.to_str().unwrap(),
        "--rig",
        "virtual:textured-plane",
        "--to",
        "gst:nosuchsink",
    ]);
    assert_code(&o, 2);
    assert!(stderr(&o).contains("nosuchsink"), "{}", stderr(&o));
    let (o, _) = play_json(&[
        "--model",
        m,
        "--source",
        film.to_str().unwrap(),
        "--rig",
        "virtual:textured-plane",
        "--to",
        "file:out.gif",
    ]);
    assert_code(&o, 2);
    assert!(stderr(&o).contains("ending"), "{}", stderr(&o));
}

#[test]
fn the_service_plays_a_playlist_from_its_configuration() {
    use crate::service::{Service, client, write_config};
    if gpu().is_none() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let (a, b) = (dir.path().join("a.mp4"), dir.path().join("b.mp4"));
    make_film(&a, 90, 64, 48, true);
    make_film(&b, 45, 48, 64, false);
    let config = write_config(dir.path(), "textured-plane", 5, "", "enabled = false");
    let text = std::fs::read_to_string(&config).unwrap().replace(
        "source = \"pattern:bars?size=200x150&fps=30\"\n",
        &format!(
            "source = [{{ src = \"{}\" }}, {{ src = \"file:{}\", loop = 2 }}]\n\
             repeat = true\n\n[audio]\ndevice = \"fakesink sync=true\"\n",
            a.display(),
            b.display()
        ),
    );
    std::fs::write(&config, text).unwrap();
    let mut svc = Service::start(&config);
    let item = |s: &serde_json::Value| s["media"]["item"]["index"].as_u64().unwrap_or(0);
    // The first item plays once a model is installed; status names it and where it is.
    let s = svc.wait_for("the first item playing", 300, |s| {
        s["state"] == "playing" && item(s) == 1 && s["media"]["position_s"].as_f64() > Some(0.2)
    });
    assert_eq!(s["media"]["item"]["count"], 2, "{s}");
    assert_eq!(s["media"]["audio"], true, "{s}");
    let o = client(&["status"], &svc.socket);
    assert_code(&o, 0);
    let text = crate::common::stdout(&o);
    assert!(text.contains("media: item 1 of 2"), "{text}");

    // Requests for sources that cannot play are refused; the film goes on.
    for (source, words) in [
        (dir.path().join("missing.mp4"), "missing"),
        (dir.path().join("notes.mp4"), "not a media file"),
    ] {
        if words != "missing" {
            std::fs::write(&source, "not a film\n".repeat(100)).unwrap();
        }
        let r = svc.ask(&format!(
            r#"{{"cmd":"play","source":"{}"}}"#,
            source.display()
        ));
        assert_eq!(r["ok"], false, "{r}");
        assert!(r["error"].as_str().unwrap().contains(words), "{r}");
    }
    // A pipeline is not taken from a client: it could run any element as the service.
    let r = svc.ask(r#"{"cmd":"play","source":"gst:videotestsrc ! fakesink"}"#);
    assert_eq!(r["ok"], false, "{r}");
    assert!(
        r["error"]
            .as_str()
            .unwrap()
            .contains("not taken from a client"),
        "{r}"
    );
    let s = svc.status();
    assert_eq!(s["state"], "playing", "{s}");
    assert_eq!(item(&s), 1, "{s}");

    // Pause holds the film; play resumes it; seek moves it.
    let r = svc.ask(r#"{"cmd":"pause"}"#);
    assert_eq!(r["ok"], true, "{r}");
    let s = svc.wait_for("paused media", 10, |s| {
        s["state"] == "paused" && s["media"]["paused"] == true
    });
    let at = s["media"]["position_s"].as_f64().unwrap();
    std::thread::sleep(Duration::from_millis(600));
    let s = svc.status();
    assert!(
        (s["media"]["position_s"].as_f64().unwrap() - at).abs() < 0.1,
        "a paused film stays where it is: {s}"
    );
    let r = svc.ask(r#"{"cmd":"play"}"#);
    assert_eq!(r["ok"], true, "{r}");
    svc.wait_for("playing again", 10, |s| {
        s["state"] == "playing" && s["media"]["paused"] == false
    });
    let r = svc.ask(r#"{"cmd":"seek","position_s":0.1}"#);
    assert_eq!(r["ok"], true, "{r}");
    let r = svc.ask(r#"{"cmd":"seek","position_s":-1}"#);
    assert_eq!(r["ok"], false, "{r}");

    // Next: the second item, played twice, then the first again (the list repeats).
    let o = client(&["next"], &svc.socket);
    assert_code(&o, 0);
    let s = svc.wait_for("the second item", 20, |s| item(s) == 2);
    assert_eq!(s["media"]["size"], serde_json::json!([48, 64]), "{s}");
    svc.wait_for("its second pass", 20, |s| {
        item(s) == 2 && s["media"]["item"]["pass"] == 2
    });
    svc.wait_for("the first item again", 20, |s| item(s) == 1);
    let o = client(&["previous"], &svc.socket);
    assert_code(&o, 0);
    svc.wait_for("the second item again", 20, |s| item(s) == 2);
    let r = svc.ask(r#"{"cmd":"stop"}"#);
    assert_eq!(r["ok"], true, "{r}");
    assert_eq!(svc.wait_exit(30), Some(0));
    let log = svc.log();
    assert!(log.contains("playlist: item 2 of 2"), "{log}");
}

#[test]
fn another_programs_screen_is_captured_and_compensated_under_xvfb() {
    if gpu().is_none() {
        return;
    }
    let Some(x) = crate::window::Xvfb::start(160, 120) else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let model = tiny_model(dir.path());
    let m = model.to_str().unwrap();
    let screen = format!("screen:x11?display={}&fps=20", x.display);
    let (o, v) = play_json(&[
        "--model",
        m,
        "--source",
        &screen,
        "--rig",
        "virtual:textured-plane",
        "--pace",
        "source",
        "--frames",
        "4",
        "--json",
    ]);
    assert_code(&o, 0);
    let v = v.unwrap();
    assert_eq!(count(&v, "shown"), 4, "{v}");
    assert_eq!(v["media"]["size"], serde_json::json!([160, 120]), "{v}");
    // A live pipeline that ends after its first frames (a stream that dropped) is started
    // again after a second, the last frame held meanwhile.
    let (o, v) = play_json(&[
        "--model",
        m,
        "--source",
        "gst:videotestsrc is-live=true num-buffers=6 ! video/x-raw,width=40,height=30,framerate=30/1",
        "--rig",
        "virtual:textured-plane",
        "--frames",
        "150",
        "--json",
    ]);
    assert_code(&o, 0);
    let v = v.unwrap();
    assert!(v["media"]["reconnects"].as_u64().unwrap() >= 1, "{v}");
    assert!(count(&v, "received") >= 12, "{v}");
    assert!(
        v["media"]["last_problem"]
            .as_str()
            .unwrap()
            .contains("the stream ended"),
        "{v}"
    );
    // A display that is not there: refused in words before any frame.
    let (o, _) = play_json(&[
        "--model",
        m,
        "--source",
        "screen:x11?display=:987",
        "--rig",
        "virtual:textured-plane",
    ]);
    assert_code(&o, 2);
    assert!(stderr(&o).contains("screen :987"), "{}", stderr(&o));
}
