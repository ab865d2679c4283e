//! The projector window under Xvfb: present a known image (and a compensated frame from the GPU
//! pass) and read the screen back with ImageMagick's `import`. Each test starts its own Xvfb on a
//! free display (`-displayfd`); without Xvfb or a GPU adapter the tests are skipped with a printed
//! reason, unless COMPEND_REQUIRE_GPU_ADAPTER=1.

use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::Duration;

use compend::raster::{ImageSize, PrjImage, Rgb, Unspecified};
use rand::rngs::ChaCha8Rng;
use rand::{RngExt, SeedableRng};

use crate::common::{gpu, skip_or_fail};

/// A running Xvfb, killed on drop.
pub(crate) struct Xvfb {
    child: Child,
    /// The X display, e.g. `:5`.
    pub(crate) display: String,
}

impl Xvfb {
    /// A screen of `w`×`h` on a free display; None (after saying why) without Xvfb.
    pub(crate) fn start(w: usize, h: usize) -> Option<Self> {
        let spawned = Command::new("Xvfb")
            .args([
                "-displayfd",
                "1",
                "-screen",
                "0",
                &format!("{w}x{h}x24"),
                "-nolisten",
                "tcp",
            ])
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn();
        let mut child = match spawned {
            Ok(c) => c,
            Err(e) => {
                skip_or_fail(&format!("Xvfb is not installed ({e})"));
                return None;
            }
        };
        let mut line = String::new();
        BufReader::new(child.stdout.take().unwrap())
            .read_line(&mut line)
            .unwrap();
        let n: u32 = line.trim().parse().expect("Xvfb prints its display number");
        Some(Self {
            child,
            display: format!(":{n}"),
        })
    }

    /// The screen as an image (`import -window root`).
    fn screenshot(&self, path: &Path) -> PrjImage {
        let o = Command::new("import")
            .args([
                "-display",
                &self.display,
                "-window",
                "root",
                path.to_str().unwrap(),
            ])
            .output()
            .expect("ImageMagick's import runs");
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        compend::pngio::read_rgb(path).unwrap()
    }
}

impl Drop for Xvfb {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// An X server with several monitors side by side: Xorg with the dummy video driver (two or
/// more RandR outputs, as on a projection PC with one projector per output), each output set to
/// `w`×`h` at 60 Hz by xrandr. Killed on drop. None (after saying why) without Xorg's dummy
/// driver or xrandr.
pub(crate) struct XDummy {
    child: Child,
    _dir: tempfile::TempDir,
    pub(crate) display: String,
    pub(crate) head: ImageSize,
}

impl XDummy {
    pub(crate) fn start(w: usize, h: usize, heads: usize) -> Option<Self> {
        let dir = tempfile::tempdir().unwrap();
        // A 60 Hz mode of w×h: a small blanking, the pixel clock in MHz.
        let (ht, vt) = (w + 24, h + 6);
        let clock = (ht * vt * 60) as f64 / 1e6;
        let conf = dir.path().join("xorg.conf");
        std::fs::write(
            &conf,
            "Section \"Device\"\n  Identifier \"d\"\n  Driver \"dummy\"\n  VideoRam 65536\n\
             EndSection\nSection \"Monitor\"\n  Identifier \"m\"\n  HorizSync 0.5-1000.0\n  \
             VertRefresh 5.0-200.0\nEndSection\nSection \"Screen\"\n  Identifier \"s\"\n  \
             Device \"d\"\n  Monitor \"m\"\n  DefaultDepth 24\n  SubSection \"Display\"\n    \
             Depth 24\n    Virtual 1024 768\n  EndSubSection\nEndSection\n",
        )
        .unwrap();
        let spawned = Command::new("Xorg")
            .args(["-displayfd", "1", "-noreset", "-nolisten", "tcp", "-config"])
            .arg(&conf)
            .arg("-logfile")
            .arg(dir.path().join("Xorg.log"))
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn();
        let mut child = match spawned {
            Ok(c) => c,
            Err(e) => {
                skip_or_fail(&format!("Xorg is not installed ({e})"));
                return None;
            }
        };
        let mut line = String::new();
        BufReader::new(child.stdout.take().unwrap())
            .read_line(&mut line)
            .unwrap();
        let Ok(n) = line.trim().parse::<u32>() else {
            let _ = child.kill();
            let log = std::fs::read_to_string(dir.path().join("Xorg.log")).unwrap_or_default();
            skip_or_fail(&format!(
                "Xorg with the dummy driver did not start (xserver-xorg-video-dummy): {}",
                log.lines()
                    .filter(|l| l.contains("(EE)"))
                    .collect::<Vec<_>>()
                    .join("; ")
            ));
            return None;
        };
        let x = Self {
            child,
            _dir: dir,
            display: format!(":{n}"),
            head: ImageSize::new(w, h),
        };
        let name = format!("{w}x{h}");
        let xrandr = |args: &[&str]| x.xrandr(args);
        let timing: Vec<String> = [
            format!("{clock:.4}"),
            w.to_string(),
            (w + 8).to_string(),
            (w + 16).to_string(),
            ht.to_string(),
            h.to_string(),
            (h + 2).to_string(),
            (h + 4).to_string(),
            vt.to_string(),
        ]
        .into();
        let mut newmode = vec!["--newmode", name.as_str()];
        newmode.extend(timing.iter().map(String::as_str));
        xrandr(&newmode);
        let mut set: Vec<String> = Vec::new();
        for k in 0..heads {
            xrandr(&["--addmode", &format!("DUMMY{k}"), &name]);
            set.extend([
                "--output".into(),
                format!("DUMMY{k}"),
                "--mode".into(),
                name.clone(),
                "--pos".into(),
                format!("{}x0", k * w),
            ]);
        }
        let set: Vec<&str> = set.iter().map(String::as_str).collect();
        xrandr(&set);
        xrandr(&["--fb", &format!("{}x{h}", w * heads)]);
        Some(x)
    }

    /// Runs xrandr on this server; panics with its error when it fails.
    pub(crate) fn xrandr(&self, args: &[&str]) {
        let o = Command::new("xrandr")
            .arg("-display")
            .arg(&self.display)
            .args(args)
            .output()
            .expect("xrandr runs (x11-xserver-utils)");
        assert!(
            o.status.success(),
            "xrandr {args:?}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
    }

    /// What monitor `k` shows.
    pub(crate) fn screenshot(&self, dir: &Path, k: usize) -> PrjImage {
        let path = dir.join(format!("head{k}.png"));
        let o = Command::new("import")
            .args(["-display", &self.display, "-window", "root", "-crop"])
            .arg(format!(
                "{}x{}+{}+0",
                self.head.width,
                self.head.height,
                k * self.head.width
            ))
            .arg("+repage")
            .arg(&path)
            .output()
            .expect("ImageMagick's import runs");
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        compend::pngio::read_rgb(&path).unwrap()
    }
}

impl Drop for XDummy {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Starts `compend ARGS` on the display and waits until its stderr says `ready`; the child is
/// killed on drop.
pub(crate) struct Running(Child);

impl Running {
    pub(crate) fn start(display: &str, args: &[&str], ready: &str) -> Self {
        let mut child = Command::new(env!("CARGO_BIN_EXE_compend"))
            .args(args)
            .env("DISPLAY", display)
            .env_remove("WAYLAND_DISPLAY")
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        let stderr = child.stderr.take().unwrap();
        let (tx, rx) = mpsc::channel();
        let ready = ready.to_string();
        std::thread::spawn(move || {
            let mut seen = String::new();
            for line in BufReader::new(stderr).lines().map_while(|l| l.ok()) {
                seen.push_str(&line);
                seen.push('\n');
                if line.contains(&ready) {
                    let _ = tx.send(Ok(()));
                }
            }
            let _ = tx.send(Err(seen));
        });
        match rx.recv_timeout(Duration::from_secs(60)) {
            Ok(Ok(())) => {}
            Ok(Err(log)) => panic!("compend {args:?} ended before presenting:\n{log}"),
            Err(_) => panic!("compend {args:?} did not present within 60 s"),
        }
        // Let the presented frame land on the screen.
        std::thread::sleep(Duration::from_millis(500));
        Running(child)
    }
}

impl Drop for Running {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

const SCREEN: ImageSize = ImageSize::new(96, 64);

#[test]
fn window_shows_a_known_image_exactly() {
    let Some(_ctx) = gpu() else { return };
    let Some(x) = Xvfb::start(SCREEN.width, SCREEN.height) else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(4);
    let known: PrjImage = Rgb::from_fn(SCREEN.width, SCREEN.height, |x, y| {
        let n: f32 = rng.random_range(0.0..1.0);
        [x as f32 / 95.0, y as f32 / 63.0, n]
    });
    let known = compend::pngio::quantize(&known);
    let path = dir.path().join("known.png");
    compend::pngio::write_rgb(&path, &known).unwrap();
    let _show = Running::start(
        &x.display,
        &["show", path.to_str().unwrap(), "--seconds", "60"],
        "presented",
    );
    let shot = x.screenshot(&dir.path().join("shot.png"));
    assert_eq!(shot.size(), SCREEN);
    assert!(shot == known, "the screen differs from the presented image");
}

#[test]
fn window_presents_the_compensated_frame() {
    let Some(_ctx) = gpu() else { return };
    let Some(x) = Xvfb::start(SCREEN.width, SCREEN.height) else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let model_dir = crate::play::tiny_model(dir.path());
    let content: Rgb<Unspecified> =
        Rgb::from_fn(40, 30, |x, y| [x as f32 / 39.0, 0.6, y as f32 / 29.0]);
    let content = compend::pngio::quantize(&content);
    let path = dir.path().join("content.png");
    compend::pngio::write_rgb(&path, &content).unwrap();
    let _play = Running::start(
        &x.display,
        &[
            "play",
            "--model",
            model_dir.to_str().unwrap(),
            "--source",
            path.to_str().unwrap(),
        ],
        "first frame presented",
    );
    let shot = x.screenshot(&dir.path().join("shot.png"));
    // The CPU reference of the same frame on a display of the screen's size.
    let model = compend::model::Model::load(&model_dir).unwrap();
    let p =
        compend::playback::Placement::for_model(&model, SCREEN, compend::fov::DisplayRange::FULL)
            .unwrap();
    let frame = compend::playback::ContentFrame::from_image(&content);
    let expected = compend::playback::reference_frame(&model, &frame, &p).unwrap();
    let worst = shot
        .data()
        .iter()
        .zip(expected.data())
        .map(|(s, e)| ((s * 255.0).round() as i32 - compend::pngio::to_u8(*e) as i32).abs())
        .max()
        .unwrap();
    assert!(worst <= 1, "screen vs CPU reference: {worst} 8-bit steps");
}
