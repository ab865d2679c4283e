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

/// Starts `compend ARGS` on the display and waits until its stderr says `ready`; the child is
/// killed on drop.
struct Running(Child);

impl Running {
    fn start(display: &str, args: &[&str], ready: &str) -> Self {
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
