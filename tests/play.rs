//! `compend play` on the virtual rig: raw frames on standard input, patterns and images through
//! the GPU pass, with frame counts checked; usage errors exit with 2. The playback loop itself
//! through the library, on a display that records what it is asked.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

use compend::player::{PlayStats, Player, Refresh, Screen, Show};
use compend::raster::ImageSize;

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
    // As under a system service: no session, no Wayland.
    let mut child = Command::new(env!("CARGO_BIN_EXE_compend"))
        .arg("play")
        .args(args)
        .env_remove("XDG_RUNTIME_DIR")
        .env_remove("NODEVICE_SELECT")
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
    let offline = |out: &std::path::Path| {
        play_with_stdin(
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
        )
    };
    let (o, v) = offline(&out);
    assert_code(&o, 0);
    // Nothing is wrong, and nothing says so (Mesa's device-select layer looked for Wayland).
    assert!(!stderr(&o).contains("XDG_RUNTIME_DIR"), "{}", stderr(&o));
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
            ImageSize::new(80, 60),
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
    // `play ... --json | true`: its reader gone before the record is printed, it exits quietly.
    let mut child = Command::new(env!("CARGO_BIN_EXE_compend"))
        .args([
            "play", "--model", m, "--source", src, "--rig", "virtual", "--pace", "source",
        ])
        .arg("--json")
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    drop(child.stdout.take());
    let mut pipe = child.stdin.take().unwrap();
    pipe.write_all(&frames).unwrap();
    drop(pipe);
    let o = child.wait_with_output().unwrap();
    assert_code(&o, 0);
    assert!(!stderr(&o).contains("panicked"), "{}", stderr(&o));
    // Into a folder an earlier `play` wrote into: its files are replaced.
    assert_code(&offline(&out).0, 0);
    // Into a folder holding a file of one of its names that it did not write: refused, kept.
    let mine = dir.path().join("mine");
    std::fs::create_dir(&mine).unwrap();
    std::fs::write(mine.join("cam_000002.png"), "mine").unwrap();
    let o = offline(&mine).0;
    assert_code(&o, 2);
    assert!(
        stderr(&o).contains("not written by `compend play`"),
        "{}",
        stderr(&o)
    );
    assert_eq!(
        std::fs::read_to_string(mine.join("cam_000002.png")).unwrap(),
        "mine"
    );
    assert!(!mine.join("play.json").exists());

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

    assert_usage_errors(m);
}

/// `compend play` usage errors exit with 2 and name what is wrong (`m`: a model directory); the
/// source spellings are documented in --help.
fn assert_usage_errors(m: &str) {
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
        // A device named as a bare path: how to spell it as a raw source.
        (
            vec!["--model", m, "--source", "/dev/zero", "--rig", "virtual"],
            "not a regular file (a FIFO or a device); to play raw frames from it, spell it raw:",
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

/// A display that records what the playback loop asks of it; with [`Refresh::Vsync`] each
/// present takes one period, as a window's does.
struct Recorder<'a> {
    ctx: &'a compend::gpu::GpuContext,
    refresh: Refresh,
    /// (sequence number, index) of each new frame presented.
    new: Vec<(u64, u64)>,
    again: u64,
    began: Option<bool>,
    finished: bool,
}

impl<'a> Recorder<'a> {
    fn new(ctx: &'a compend::gpu::GpuContext, refresh: Refresh) -> Self {
        Self {
            ctx,
            refresh,
            new: Vec::new(),
            again: 0,
            began: None,
            finished: false,
        }
    }
}

impl Screen for Recorder<'_> {
    fn context(&self) -> &compend::gpu::GpuContext {
        self.ctx
    }
    fn refresh(&self) -> Refresh {
        self.refresh
    }
    fn begin(&mut self, live: bool) -> compend::Result<()> {
        self.began = Some(live);
        Ok(())
    }
    fn present(
        &mut self,
        _pass: &compend::gpu::CompensationPass,
        show: Show,
    ) -> compend::Result<()> {
        match show {
            Show::New { seq, index } => self.new.push((seq, index)),
            Show::Again => self.again += 1,
        }
        if let Refresh::Vsync(hz) = self.refresh {
            std::thread::sleep(std::time::Duration::from_secs_f64(1.0 / hz));
        }
        Ok(())
    }
    fn finish(&mut self, _stats: &mut PlayStats) -> compend::Result<()> {
        self.finished = true;
        Ok(())
    }
}

/// The one playback loop through the library, on displays with and without a refresh of their
/// own: offline every frame once; a still image held on a vsync display and ended on a timer
/// one; live counts that add up.
#[test]
fn one_loop_paces_and_counts_for_every_screen() {
    use compend::fov::DisplayRange;
    use compend::source::{FeedMode, Pattern, SourceSpec};

    let Some(ctx) = gpu() else { return };
    let model = crate::gpu::test_model(1);
    let display = ImageSize::new(64, 48);
    let start = |spec: &SourceSpec, mode| {
        let source = compend::source::open(spec).unwrap();
        Player::start(ctx, &model, display, DisplayRange::FULL, source, mode).unwrap()
    };
    let pattern = |fps, frames| SourceSpec::Pattern {
        pattern: Pattern::Moving,
        size: ImageSize::new(32, 24),
        fps,
        frames,
    };

    // Offline on a display without a refresh of its own: every frame once, in order.
    let mut screen = Recorder::new(ctx, Refresh::Timer(60.0));
    let s = start(&pattern(240.0, Some(5)), FeedMode::Queue)
        .run(&mut screen, None)
        .unwrap();
    assert_eq!(screen.new, (1..=5).map(|i| (i, i)).collect::<Vec<_>>());
    assert_eq!(screen.began, Some(false));
    assert!(screen.finished);
    let counts = (s.refreshes, s.shown, s.held, s.received);
    assert_eq!(counts, (5, 5, 0, 5), "{s:?}");
    assert_eq!(
        (s.dropped_source, s.dropped_pipeline, s.refresh_hz),
        (0, 0, 0.0)
    );

    // A still image: held on a vsync display until the refreshes run out ...
    let dir = tempfile::tempdir().unwrap();
    let img = dir.path().join("still.png");
    compend::pngio::write_rgb(
        &img,
        &compend::raster::Rgb::<compend::raster::Unspecified>::filled(24, 16, [0.8, 0.5, 0.2]),
    )
    .unwrap();
    let still = SourceSpec::Image(img);
    let mut screen = Recorder::new(ctx, Refresh::Vsync(120.0));
    let s = start(&still, FeedMode::Latest)
        .run(&mut screen, Some(6))
        .unwrap();
    assert_eq!((s.refreshes, s.shown, s.held), (6, 1, 5), "{s:?}");
    assert_eq!(screen.new, vec![(1, 1)]);
    assert!(screen.again >= 1 && screen.again <= 5);
    assert_eq!((screen.began, s.refresh_hz), (Some(true), 120.0));
    // ... and ended after its frame on a display without one.
    let mut screen = Recorder::new(ctx, Refresh::Timer(120.0));
    let s = start(&still, FeedMode::Latest)
        .run(&mut screen, None)
        .unwrap();
    assert_eq!((s.shown, screen.new.len()), (1, 1), "{s:?}");

    // Live at 120 Hz from a 40 fps source: every refresh shows a new frame or holds one.
    let mut screen = Recorder::new(ctx, Refresh::Timer(120.0));
    let s = start(&pattern(40.0, None), FeedMode::Latest)
        .run(&mut screen, Some(24))
        .unwrap();
    assert_eq!(s.refreshes, 24, "{s:?}");
    assert_eq!(s.shown + s.held, s.refreshes, "{s:?}");
    assert!(s.shown >= 1 && s.received >= s.shown, "{s:?}");
    assert_eq!(s.refresh_hz, 120.0);
}
