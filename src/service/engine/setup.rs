//! The setup view, for a first rig: a test pattern projected as it is (no model needed), the
//! camera watched at its full rate with a focus figure and the share of clipped pixels, every
//! frame offered to the console. It ends with the next request that asks for something else
//! (play, pause, calibrate, another pattern, stop).

use std::time::{Duration, Instant};

use super::super::devices::Devices;
use super::super::protocol::{SetupStatus, State};
use super::{Engine, Mode};
use crate::device::{DisplaySink, FrameSource};
use crate::error::Result;
use crate::patterns::SetupPattern;

/// How often the status gets the setup figures.
const STATUS_PERIOD: Duration = Duration::from_millis(200);

impl Engine {
    /// Projects `pattern` and watches the camera until another request comes.
    pub(super) fn setup(&mut self, pattern: SetupPattern) {
        if let Err(e) = self.run_setup(pattern) {
            self.io.fail("setup view", &e);
            if self.mode == Mode::Wait {
                self.io.state(State::Idle, "idle: the setup view failed");
            }
        }
        self.io.shared.update(|s| s.setup = None);
    }

    fn run_setup(&mut self, pattern: SetupPattern) -> Result<()> {
        let image = pattern.render(self.devices.display_size());
        let shared = self.io.shared.clone();
        let line = format!("setup: the {pattern} pattern is up");
        self.io.state(State::Setup, &line);
        self.io.notify.ready(&line);
        tracing::info!("{line}; the camera is watched at its full rate");
        let mut frames = 0u64;
        let mut told = Instant::now() - STATUS_PERIOD;
        let mut look = |f: &crate::device::Frame| {
            frames += 1;
            shared.views.offer_camera_now(&f.image);
            if told.elapsed() >= STATUS_PERIOD {
                told = Instant::now();
                let sharpness = crate::metrics::sharpness(&f.image);
                let (high, low) = crate::metrics::clipping(&f.image);
                shared.update(|s| {
                    s.setup = Some(SetupStatus {
                        pattern: pattern.to_string(),
                        frames,
                        sharpness,
                        clipped_pct: 100.0 * high,
                        crushed_pct: 100.0 * low,
                    })
                });
            }
        };
        loop {
            // Shown again before each look: a window keeps presenting, and the virtual camera
            // sees what was shown last.
            let grabbed = match &mut self.devices {
                Devices::Virtual(v) => {
                    v.rig.show(&image)?;
                    v.rig.grab()
                }
                Devices::Hardware(h) => {
                    h.win.show(&image)?;
                    match h.camera.grab() {
                        Ok(f) => Ok(f),
                        Err(e) if h.camera.reconnect()? => {
                            tracing::warn!("setup view: the camera came back after: {e}");
                            continue;
                        }
                        Err(e) => Err(e),
                    }
                }
                // Every projector of a set shows the pattern.
                Devices::Set(s) => {
                    s.show_all(&image)?;
                    let camera = s.camera();
                    match camera.grab() {
                        Ok(f) => Ok(f),
                        Err(e) if camera.reconnect()? => {
                            tracing::warn!("setup view: the camera came back after: {e}");
                            continue;
                        }
                        Err(e) => Err(e),
                    }
                }
            };
            look(&grabbed?);
            self.io.notify.ping();
            while let Ok(ev) = self.io.rx.try_recv() {
                self.handle(ev);
            }
            if self.mode != Mode::Wait {
                return Ok(());
            }
        }
    }
}
