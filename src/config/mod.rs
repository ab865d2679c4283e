//! The service's configuration (`compend serve --config F`, `compend calibrate --config F`,
//! `compend config check F`): a TOML file, every key optional, unknown keys rejected, and every
//! error in a file reported at once, each with its line.
//!
//! The shipped `config/compend.toml` documents every key; a test checks that it parses and that
//! it names every key this parser knows ([`known_keys`]).
//!
//! How it reads ([`read`]): the document is parsed with spans ([`toml::de::DeTable`]), then
//! each section is walked key by key: a key is taken out of its table, deserialised on its own
//! and checked, and whatever is left in a table at the end is an unknown key (with the nearest
//! known one suggested). So one bad value does not hide the next, and the typed [`Config`] below
//! is the only statement of what the file may hold.
//!
//! Each section is a file of its own: its type, its defaults on the type (`Default`, or a
//! constructor where they follow the state directory: [`PathsConfig::under`],
//! [`PlaybackConfig::defaults`]) and its reader, which falls back to those defaults.

use std::path::Path;

use serde::Serialize;

use crate::error::Result;

mod audio;
mod calibration;
mod http;
mod log;
mod monitoring;
mod osc;
mod output;
mod paths;
mod playback;
mod read;
mod rig;
mod socket;

pub use audio::AudioConfig;
pub use calibration::{CalibrationConfig, OnStart};
pub use http::{DEFAULT_HTTP, HttpConfig, TlsFiles};
pub use log::LogConfig;
pub use monitoring::{DriftPolicy, MonitoringConfig};
pub use osc::OscConfig;
pub use output::OutputConfig;
pub use paths::PathsConfig;
pub use playback::PlaybackConfig;
pub use rig::{ProjectorConfig, RigConfig, RigKind};
pub use socket::SocketConfig;

use read::{Table, Walker};

/// The whole configuration.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Config {
    pub rig: RigConfig,
    pub paths: PathsConfig,
    pub calibration: CalibrationConfig,
    pub playback: PlaybackConfig,
    pub audio: AudioConfig,
    pub output: OutputConfig,
    pub monitoring: MonitoringConfig,
    pub socket: SocketConfig,
    pub http: HttpConfig,
    pub osc: OscConfig,
    pub log: LogConfig,
}

fn display_or_none<T: std::fmt::Display, S: serde::Serializer>(
    v: &Option<T>,
    s: S,
) -> std::result::Result<S::Ok, S::Error> {
    match v {
        Some(v) => s.collect_str(v),
        None => s.serialize_str("none"),
    }
}

fn display<T: std::fmt::Display, S: serde::Serializer>(
    v: &T,
    s: S,
) -> std::result::Result<S::Ok, S::Error> {
    s.collect_str(v)
}

fn displayed_list<T: std::fmt::Display, S: serde::Serializer>(
    v: &[T],
    s: S,
) -> std::result::Result<S::Ok, S::Error> {
    s.collect_seq(v.iter().map(|x| x.to_string()))
}

impl Config {
    /// Every key at its default, as each section's type declares it (the state and socket
    /// paths from systemd's environment when it sets them).
    pub fn defaults() -> Self {
        let paths = PathsConfig::under(paths::default_state());
        Config {
            rig: RigConfig::default(),
            calibration: CalibrationConfig::default(),
            playback: PlaybackConfig::defaults(&paths.state),
            audio: AudioConfig::default(),
            output: OutputConfig::default(),
            monitoring: MonitoringConfig::default(),
            socket: SocketConfig::default(),
            http: HttpConfig::default(),
            osc: OscConfig::default(),
            log: LogConfig::default(),
            paths,
        }
    }

    /// Reads and parses `path`.
    pub fn load(path: &Path) -> Result<Self> {
        let text = crate::files::read_text(path, "a compend configuration file (TOML)")?;
        Self::parse(&text, path)
    }

    /// Parses a configuration; `path` names the file in messages. Every problem is reported,
    /// one per line, in one [`crate::Error::Input`].
    pub fn parse(text: &str, path: &Path) -> Result<Self> {
        let mut w = Walker::new(text, path);
        let config = w.document();
        match (config, w.errors.is_empty()) {
            (Some(c), true) => Ok(c),
            _ => Err(w.into_error()),
        }
    }
}

/// Every `section.key` the parser knows, in the order it reads them.
pub fn known_keys() -> Vec<String> {
    let mut w = Walker::new("", Path::new("(keys)"));
    let _ = w.document();
    w.asked
}

/// Every section of the document `root`, in the order of the shipped file, each read by its
/// type's reader; what is left in a section is an unknown key.
fn sections<'t>(w: &mut Walker<'t>, root: &mut Table<'t>) -> Config {
    fn section<'t, T>(
        w: &mut Walker<'t>,
        root: &mut Table<'t>,
        name: &'static str,
        read: impl FnOnce(&mut Walker<'t>, &mut Table<'t>) -> T,
    ) -> T {
        let mut t = w.table(root, name);
        let value = read(w, &mut t);
        w.finish(t);
        value
    }
    let mut rig = section(w, root, "rig", RigConfig::read);
    rig::ProjectorConfig::read_into(w, root, &mut rig);
    let paths = section(w, root, "paths", PathsConfig::read);
    let calibration = section(w, root, "calibration", CalibrationConfig::read);
    let playback = section(w, root, "playback", |w, t| {
        PlaybackConfig::read(w, t, &paths.state)
    });
    Config {
        rig,
        calibration,
        playback,
        audio: section(w, root, "audio", AudioConfig::read),
        output: section(w, root, "output", OutputConfig::read),
        monitoring: section(w, root, "monitoring", MonitoringConfig::read),
        socket: section(w, root, "socket", SocketConfig::read),
        http: section(w, root, "http", HttpConfig::read),
        osc: section(w, root, "osc", OscConfig::read),
        log: section(w, root, "log", LogConfig::read),
        paths,
    }
}

#[cfg(test)]
mod tests {
    use super::read::SECTIONS;
    use super::*;

    fn parse(text: &str) -> Result<Config> {
        Config::parse(text, Path::new("t.toml"))
    }

    #[test]
    fn an_empty_file_is_the_defaults() {
        let c = parse("").unwrap();
        // Each section's defaults, declared on its type, are what the reader falls back to.
        assert_eq!(c, Config::defaults());
        assert_eq!(c.rig.kind, RigKind::Virtual);
        assert_eq!(
            c.calibration.ntrain,
            crate::calibrate::SamplingCount::Count(48)
        );
        assert_eq!(c.paths.model, c.paths.state.join("model"));
        assert_eq!(c.socket.mode, 0o660);
    }

    #[test]
    fn every_error_is_reported_with_its_line() {
        let text = "[rig]\nkind = \"projector\"\nsede = 3\n[calibration]\nntrain = \"many\"\n\
                    verify = 0\n[socket]\nmode = \"rw\"\n[sockets]\n";
        let e = parse(text).unwrap_err().to_string();
        for want in [
            "t.toml:2: [rig] kind: \"projector\" is not one of",
            "t.toml:3: unknown key `sede` at the [rig]; did you mean `seed`?",
            "t.toml:5: [calibration] ntrain:",
            "t.toml:6: [calibration] verify: must be at least 1",
            "t.toml:8: [socket] mode: \"rw\" is not a file mode",
            "t.toml:9: unknown key `sockets` at the top level; did you mean `socket`?",
            "6 errors",
        ] {
            assert!(e.contains(want), "missing {want:?} in:\n{e}");
        }
    }

    #[test]
    fn ntrain_takes_a_count_or_auto_for_a_method_that_starts_from_linear() {
        use crate::calibrate::SamplingCount;
        let c = parse("[calibration]\nntrain = \"auto\"\n").unwrap();
        assert_eq!(c.calibration.ntrain, SamplingCount::Auto);
        let c = parse("[calibration]\nntrain = 24\n").unwrap();
        assert_eq!(c.calibration.ntrain, SamplingCount::Count(24));
        for (text, says) in [
            (
                "[calibration]\nmethod = \"compennet++-cpu\"\nntrain = \"auto\"\n",
                "t.toml:3: [calibration] ntrain = \"auto\": the sampling rounds are scored \
                 with the linear rung, which compennet++-cpu does not start from",
            ),
            (
                "[calibration]\nntrain = \"lots\"\n",
                "t.toml:2: [calibration] ntrain: \"lots\": expected a number of sampling \
                 images, or \"auto\"",
            ),
            (
                "[calibration]\nntrain = 2\n",
                "t.toml:2: [calibration] ntrain: at least 4",
            ),
        ] {
            let e = parse(text).unwrap_err().to_string();
            assert!(e.contains(says), "{e}");
        }
    }

    #[test]
    fn broken_toml_is_named() {
        let e = parse("[rig\nkind = 1").unwrap_err().to_string();
        assert!(e.contains("t.toml:1: not valid TOML"), "{e}");
        let e = parse("[calibration]\nntrain = 12\nntrain = 13\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("t.toml:3: not valid TOML"), "{e}");
        assert!(e.contains("ntrain"), "{e}");
        // More verification images than test images: named at the line that sets them; not
        // said at all when ntest itself was wrong (its default would be quoted).
        let e = parse("[rig]\nkind = \"virtual\"\n[calibration]\nntest = 4\nverify = 6\n")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("t.toml:5: [calibration] verify = 6 is more than ntest = 4"),
            "{e}"
        );
        let e = parse("[calibration]\nntest = 0\nverify = 12\n")
            .unwrap_err()
            .to_string();
        assert!(!e.contains("more than ntest"), "{e}");
    }

    #[test]
    fn drift_refits_and_climbs_are_read_and_checked() {
        let c = parse(
            "[monitoring]\non_drift = \"refit\"\nrefit_ntrain = 5\n\
             [calibration]\nclimb = \"auto\"\n",
        )
        .unwrap();
        assert_eq!(c.monitoring.on_drift, DriftPolicy::Refit);
        assert_eq!(c.monitoring.refit_ntrain, 5);
        assert_eq!(
            c.calibration.climb,
            Some(crate::model::Method::CompenNetPpRes)
        );
        assert_eq!(c.calibration.climb_gain_db, crate::fit::DEFAULT_RIG_GAIN_DB);
        let e = parse("[monitoring]\nrefit_ntrain = 2\n[calibration]\nclimb = \"up\"\n")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("t.toml:2: [monitoring] refit_ntrain: at least 4"),
            "{e}"
        );
        assert!(
            e.contains("t.toml:4: [calibration] climb:") && e.contains("\"auto\""),
            "{e}"
        );
    }

    #[test]
    fn the_training_device_is_read_and_chooses_the_rung_auto_climbs_to() {
        let c = parse("[calibration]\nclimb = \"auto\"\n").unwrap();
        assert_eq!(c.calibration.device, crate::fit::TrainDevice::Cpu);
        let c = parse("[calibration]\ndevice = \"cpu\"\nclimb = \"auto\"\n").unwrap();
        assert_eq!(
            c.calibration.climb,
            Some(crate::model::Method::CompenNetPpRes)
        );
        let e = parse("[calibration]\ndevice = \"gpu\"\n")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("t.toml:2: [calibration] device: device `gpu`: expected `cpu`, `cuda`"),
            "{e}"
        );
        let cuda = parse("[calibration]\ndevice = \"cuda:1\"\nclimb = \"auto\"\n");
        if cfg!(feature = "cuda") {
            let c = cuda.unwrap();
            assert_eq!(c.calibration.device, crate::fit::TrainDevice::Cuda(1));
            assert_eq!(
                c.calibration.climb,
                Some(crate::model::Method::CompenNetPpResFull)
            );
        } else {
            let e = cuda.unwrap_err().to_string();
            assert!(
                e.contains(
                    "t.toml:2: [calibration] device: \"cuda:1\": this compend was built \
                            without CUDA"
                ),
                "{e}"
            );
        }
    }

    #[test]
    fn the_refresh_rate_a_climb_is_weighed_at_is_a_rate_or_0() {
        assert_eq!(parse("").unwrap().calibration.refresh_hz, None);
        let c = parse("[calibration]\nrefresh_hz = 60\n").unwrap();
        assert_eq!(c.calibration.refresh_hz, Some(60.0));
        let c = parse("[calibration]\nrefresh_hz = 0.0\n").unwrap();
        assert_eq!(c.calibration.refresh_hz, Some(0.0));
        // Every wrong value is reported, each with its line.
        let e = parse("[calibration]\nrefresh_hz = -50.0\n[rig]\nfps = \"fast\"\n")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("t.toml:2: [calibration] refresh_hz: -50: expected a refresh rate in Hz"),
            "{e}"
        );
        assert!(e.contains("t.toml:4: [rig] fps"), "{e}");
        let e = parse("[calibration]\nrefresh_hz = \"60 Hz\"\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("t.toml:2: [calibration] refresh_hz"), "{e}");
    }

    #[test]
    fn closed_loop_pairs_are_for_a_linear_rung() {
        let c = parse("[calibration]\nloop_images = 24\n").unwrap();
        assert_eq!(c.calibration.loop_images, Some(24));
        assert_eq!(parse("").unwrap().calibration.loop_images, None);
        let e = parse("[calibration]\nloop_images = 501\n")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("t.toml:2: [calibration] loop_images = 501: at most 500"),
            "{e}"
        );
        // `auto` takes them for the linear rung it keeps; explicitly none for another method
        // is fine, some is not.
        assert!(parse("[calibration]\nmethod = \"auto\"\nloop_images = 24\n").is_ok());
        assert!(parse("[calibration]\nmethod = \"compennet++-cpu\"\nloop_images = 0\n").is_ok());
        let e = parse("[calibration]\nmethod = \"compennet++-cpu\"\nloop_images = 24\n")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains(
                "t.toml:3: [calibration] loop_images = 24: only linear, linear-sl, \
                 compennet++-res, compennet++-res-full and auto"
            ),
            "{e}"
        );
    }

    #[test]
    fn a_camera_rig_needs_a_device() {
        let e = parse("[rig]\nkind = \"camera\"\n").unwrap_err().to_string();
        assert!(e.contains("needs `camera`"), "{e}");
        let c = parse("[rig]\nkind = \"camera\"\ncamera = \"/dev/video0\"\n").unwrap();
        assert_eq!(c.rig.camera.as_deref(), Some(Path::new("/dev/video0")));
    }

    #[test]
    fn durations_too_large_to_count_are_refused() {
        let e = parse("[monitoring]\nperiod_s = 1e30\n[rig]\ndrift_after_s = 1e300\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("t.toml:2: [monitoring] period_s"), "{e}");
        assert!(e.contains("t.toml:4: [rig] drift_after_s"), "{e}");
        assert!(parse("[monitoring]\nperiod_s = 86400\n").is_ok());
    }

    #[test]
    fn the_console_listens_on_loopback_and_elsewhere_only_with_a_token_and_networks() {
        let c = parse("").unwrap();
        assert_eq!(c.http.listen, Some(DEFAULT_HTTP.parse().unwrap()));
        let c = parse("[http]\nlisten = \"off\"\n").unwrap();
        assert_eq!(c.http.listen, None);
        let c = parse(
            "[http]\nlisten = \"0.0.0.0:7421\"\ntoken_file = \"/etc/t\"\n\
             allow = [\"10.0.0.0/24\", \"192.168.1.7\"]\n",
        )
        .unwrap();
        assert_eq!(c.http.allow.len(), 2);
        assert!(c.http.allow[1].contains(&"192.168.1.7".parse::<std::net::IpAddr>().unwrap()));
        let e = parse("[http]\nlisten = \"0.0.0.0:7421\"\nallow = [\"10.0.0.0/33\"]\n")
            .unwrap_err()
            .to_string();
        for want in [
            "t.toml:2: [http] listen = \"0.0.0.0:7421\" is reachable from other machines: it \
             needs token_file",
            "it needs allow",
            "t.toml:3: [http] allow: \"10.0.0.0/33\" is not a network",
        ] {
            assert!(e.contains(want), "{want:?} in:\n{e}");
        }
        let e = parse("[http]\nlisten = \"localhost\"\n")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("[http] listen: \"localhost\" is not an address"),
            "{e}"
        );
    }

    #[test]
    fn a_playlist_parses_and_its_wrong_items_are_named_at_their_line() {
        let c = parse(
            "[playback]\nsource = [\"pattern:bars\", { src = \"pattern:gray\", loop = 2, \
             duration_s = 1.5 }]\nrepeat = false\n[audio]\nenabled = false\n",
        )
        .unwrap();
        let list = &c.playback.source;
        assert_eq!(list.items.len(), 2);
        assert_eq!(list.items[1].loops, 2);
        assert_eq!(list.items[1].duration_s, Some(1.5));
        assert!(!list.repeat);
        assert_eq!(c.audio.out().sink, None);
        // One source is a playlist of one, played as `compend play` plays it.
        let c = parse("[playback]\nsource = \"pattern:gray\"\n").unwrap();
        assert_eq!(
            c.playback.source,
            crate::source::Playlist::single("pattern:gray")
        );
        let e = parse(
            "[playback]\n\nsource = [\"pattern:nope\", { src = \"pattern:gray\", loops = 2 }, \
             { loop = 1 }, 5, { src = \"pattern:gray\", duration_s = -1 }]\n",
        )
        .unwrap_err()
        .to_string();
        for want in [
            "t.toml:3: [playback] source item 1: source \"pattern:nope\": unknown pattern",
            "item 2: unknown key `loops`",
            "item 3: needs `src`",
            "item 4: expected a source's spelling",
            "item 5: duration_s must be a positive",
        ] {
            assert!(e.contains(want), "{want}: {e}");
        }
        let e = parse("[playback]\nsource = []\n").unwrap_err().to_string();
        assert!(e.contains("an empty list"), "{e}");
        let e = parse("[audio]\ndelay_ms = 1e9\ndevice = \" \"\n")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("[audio] delay_ms") && e.contains("[audio] device"),
            "{e}"
        );
        let e = parse("[output]\nto = \"file:x.gif\"\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("[output] to") && e.contains("ending"), "{e}");
        let c = parse("[output]\nto = \"gst:fakesink\"\n").unwrap();
        assert_eq!(
            c.output.to,
            Some(crate::output::OutputSpec::Pipeline("fakesink".into()))
        );
    }

    #[test]
    fn projector_sections_name_a_sets_monitors() {
        let c = parse(
            "[rig]\nkind = \"camera\"\ncamera = \"/dev/video0\"\n[[projector]]\nmonitor = \
             \"HDMI-1\"\n[[projector]]\nmonitor = \"DP-2\"\n",
        )
        .unwrap();
        assert_eq!(c.rig.projectors.len(), 2);
        assert_eq!(c.rig.monitor.as_deref(), Some("HDMI-1,DP-2"));
        // The virtual rig's sections only count its scene's projectors.
        let c = parse("[rig]\nscene = \"tiled\"\n[[projector]]\n[[projector]]\n").unwrap();
        assert_eq!((c.rig.projectors.len(), c.rig.monitor), (2, None));
        let text = "[rig]\nkind = \"window\"\nmonitor = \"HDMI-1\"\n[[projector]]\nmonitor = \
                    \"A,B\"\n[[projector]]\nmonitr = \"B\"\n[[projector]]\nmonitor = \"C\"\n";
        let e = parse(text).unwrap_err().to_string();
        for want in [
            "t.toml:5: [[projector]] 1 monitor: \"A,B\" is not one monitor's name or index",
            "t.toml:7: unknown key `monitr` at the [projector]; did you mean `monitor`?",
            "[[projector]] 2: a window rig needs each projector's monitor",
        ] {
            assert!(e.contains(want), "missing {want:?} in:\n{e}");
        }
        let e = parse("[[projector]]\nmonitor = \"HDMI-1\"\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("the virtual rig has its own outputs"), "{e}");
        let e =
            parse("[rig]\nkind = \"window\"\nmonitor = \"X\"\n[[projector]]\nmonitor = \"A\"\n")
                .unwrap_err()
                .to_string();
        assert!(e.contains("both name monitors"), "{e}");
        let e = parse("[[projector]]\nto = \"file:a.mkv\"\n[[projector]]\n")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("[[projector]] to: given for 1 of 2 projectors"),
            "{e}"
        );
        let c = parse("[[projector]]\nto = \"file:a.mkv\"\n[[projector]]\nto = \"gst:fakesink\"\n")
            .unwrap();
        assert!(c.rig.projectors.iter().all(|p| p.to.is_some()));
        let e = parse("projector = 3\n").unwrap_err().to_string();
        assert!(
            e.contains("`projector` must be sections ([[projector]])"),
            "{e}"
        );
    }

    #[test]
    fn known_keys_cover_every_section() {
        let keys = known_keys();
        for s in SECTIONS {
            assert!(keys.iter().any(|k| k.starts_with(&format!("{s}."))), "{s}");
        }
        assert!(keys.contains(&"monitoring.on_drift".to_string()));
    }
}
