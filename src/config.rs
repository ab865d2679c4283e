//! The service's configuration (`compend serve --config F`, `compend calibrate --config F`,
//! `compend config check F`): a TOML file, every key optional, unknown keys rejected, and every
//! error in a file reported at once, each with its line.
//!
//! The shipped `config/compend.toml` documents every key; a test checks that it parses and that
//! it names every key this parser knows ([`known_keys`]).
//!
//! How it reads: the document is parsed with spans ([`toml::de::DeTable`]), then each section is
//! walked key by key: a key is taken out of its table, deserialised on its own and checked, and
//! whatever is left in a table at the end is an unknown key (with the nearest known one
//! suggested). So one bad value does not hide the next, and the typed [`Config`] below is the
//! only statement of what the file may hold.

use std::ops::Range;
use std::path::{Path, PathBuf};
use std::str::FromStr;

use serde::Serialize;
use serde::de::DeserializeOwned;
use toml::Spanned;
use toml::de::{DeTable, DeValue, ValueDeserializer};

use crate::error::{Error, Result};
use crate::model::MethodChoice;
use crate::raster::ImageSize;

/// The largest value a number of seconds, hertz or milliseconds may take (about 31 years in
/// seconds): beyond it, durations overflow.
const LARGEST: f64 = 1e9;

/// Where the projector and the camera come from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum RigKind {
    /// The built-in virtual rig (simulated projector, surface and camera).
    Virtual,
    /// The projector window watched by a virtual camera (testing the display path).
    Window,
    /// The projector window and a V4L2 camera: real hardware.
    Camera,
}

/// `[rig]`: the devices.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct RigConfig {
    pub kind: RigKind,
    /// `virtual`/`window`: a built-in scene or a scene JSON file.
    pub scene: String,
    /// Seed of the sampling images (and of the virtual rig's texture and noise).
    pub seed: u64,
    /// `camera`: the V4L2 device (a /dev/v4l/by-id/ path survives re-plugging).
    pub camera: Option<PathBuf>,
    /// `camera`: the capture size; `virtual`/`window`: the virtual camera's resolution.
    pub camera_size: Option<ImageSize>,
    /// `virtual`: the projector resolution (the window's is its monitor's).
    pub projector: Option<ImageSize>,
    /// `window`/`camera`: the projector's monitor, by name or index.
    pub monitor: Option<String>,
    /// `virtual`: the display refresh rate playback is paced at, Hz.
    pub fps: f64,
    /// `virtual`/`window`: the virtual camera's frame rate, Hz (default: the scene's).
    pub camera_fps: Option<f64>,
    /// `virtual`/`window`: projector-to-camera delay, ms (default: the scene's).
    pub latency_ms: Option<f64>,
    /// `virtual`/`window`, scenes with drift: seconds after playback first starts at which the
    /// simulated projector is moved to the scene's drifted pose (a bump, for testing monitoring
    /// and recalibration).
    pub drift_after_s: Option<f64>,
}

/// `[paths]`: where models and captures live.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct PathsConfig {
    /// The state directory: models and captures (systemd's `StateDirectory=`).
    pub state: PathBuf,
    /// The calibration data root [default: STATE/calibration].
    pub data: PathBuf,
    /// The installed model directory [default: STATE/model].
    pub model: PathBuf,
    /// The folders whose model directories a `model` request may name [default: STATE].
    pub models: Vec<PathBuf>,
}

/// When the service calibrates by itself.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum OnStart {
    /// At start when no model is installed (or an interrupted calibration is on disk).
    IfNoModel,
    /// Only when asked (`compend recalibrate`).
    Never,
}

/// `[calibration]`: what `calibrate` projects and fits.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct CalibrationConfig {
    #[serde(serialize_with = "display")]
    pub method: MethodChoice,
    /// Sampling images, or `auto` (rounds, [`crate::calibrate::rounds`]).
    pub ntrain: crate::calibrate::SamplingCount,
    pub ntest: usize,
    pub verify: usize,
    /// PSNR gain over the uncompensated projection a model needs to be installed, dB.
    pub min_gain_db: f64,
    /// Frames averaged per capture.
    pub average: usize,
    /// Network size of the sampling images.
    pub network: ImageSize,
    pub on_start: OnStart,
    /// Calibration run folders the service keeps under `[paths] data` (0: all).
    pub keep_runs: usize,
    /// Progressive calibration: the rung trained in the background, on the same captures, once
    /// a calibration has installed its model and playback has started; `None`: no climb.
    #[serde(serialize_with = "display_or_none")]
    pub climb: Option<crate::model::Method>,
    /// PSNR gain (dB) the climbed rung needs over the installed model (or, under `method =
    /// "auto"`, over the best linear rung) in closed loop on the rig, on the verification
    /// images, to be installed.
    pub climb_gain_db: f64,
    /// Iterations of the climbed rung's training (the progressive climb's and `auto`'s);
    /// `None`: its own schedule.
    pub climb_iters: Option<usize>,
    /// Where the CompenNet++ rungs train (a calibration's, `auto`'s climb and the progressive
    /// climb); it also sets the rung `climb = "auto"` and `method = "auto"` climb to.
    #[serde(serialize_with = "display")]
    pub device: crate::fit::TrainDevice,
    /// Closed-loop pairs taken with the `linear` rung after its first fit (0: none; `None`:
    /// [`crate::calibrate::loop_images`]'s default, as many as `ntrain`): a linear rung (and
    /// the one `auto` keeps) is refitted on every pair, a residual rung trains its correction
    /// on them, and `auto` with 8 or more judges its climb on them
    /// ([`crate::calibrate::refine`]).
    pub loop_images: Option<usize>,
    /// The display refresh rate (Hz) a climb's live pass is weighed at (`method = "auto"`'s
    /// and the progressive climb's): the rung is timed on the playback GPU first and not
    /// trained when its pass takes more than half of one refresh period. `None`: the projector
    /// window's rate (window and camera rigs; the virtual rig's climbs are then not weighed);
    /// 0: not weighed.
    pub refresh_hz: Option<f64>,
}

/// `[playback]`.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct PlaybackConfig {
    /// What to play: one source (`compend play --help` lists the spellings) or a playlist,
    /// with `repeat`.
    pub source: crate::source::Playlist,
    /// Play the source as soon as a verified model is installed (at start and after each
    /// calibration).
    pub autoplay: bool,
    /// The folders whose files a `play` request may name (images, folders, films, raw files
    /// and FIFOs) [default: STATE/media]. The configured `source` is not limited to them.
    pub media: Vec<PathBuf>,
}

/// `[audio]`: where media sources' sound goes.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct AudioConfig {
    /// Play the sound of films and streams.
    pub enabled: bool,
    /// `auto` (PulseAudio or PipeWire, else ALSA's default device) or a GStreamer audio sink
    /// description: `alsasink device=hw:1`, `pulsesink device=NAME`, `jackaudiosink`.
    pub device: String,
    /// A trim added to the measured picture latency the sound is delayed by, ms (positive:
    /// the sound later).
    pub delay_ms: f64,
}

impl AudioConfig {
    /// The sound's way out for the sources.
    pub fn out(&self) -> crate::source::AudioOut {
        crate::source::AudioOut {
            sink: self.enabled.then(|| self.device.clone()),
            delay_ms: self.delay_ms,
        }
    }
}

/// `[output]`: the compensated frames to other software as well as the projector.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct OutputConfig {
    /// `file:PATH` (each playback to `NAME-NNNN.EXT` beside it) or `gst:PIPELINE`; None: off.
    #[serde(serialize_with = "output_or_none")]
    pub to: Option<crate::output::OutputSpec>,
}

fn output_or_none<S: serde::Serializer>(
    v: &Option<crate::output::OutputSpec>,
    s: S,
) -> std::result::Result<S::Ok, S::Error> {
    match v {
        Some(o) => s.collect_str(o),
        None => s.serialize_str("none"),
    }
}

/// What the service does when monitoring finds drift.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum DriftPolicy {
    /// Say so in `status` and the log, and keep playing.
    Report,
    /// Calibrate again (captures, fit, verification); install only if it verifies.
    Recalibrate,
    /// Refit fast: a calibration from `refit_ntrain` sampling images (seconds of captures
    /// instead of a minute), geometry and colour of the `linear` rung; installed only if it
    /// verifies. `calibrate`/`recalibrate` requests still run the full calibration.
    Refit,
}

/// `[monitoring]`: scoring the compensated projection during playback.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct MonitoringConfig {
    pub enabled: bool,
    /// Seconds between two monitoring captures.
    pub period_s: f64,
    /// Drop of the monitoring PSNR below the one measured at installation that counts as
    /// drift, dB.
    pub drift_threshold_db: f64,
    pub on_drift: DriftPolicy,
    /// `on_drift = "refit"`: sampling images the refit projects and fits on.
    pub refit_ntrain: usize,
}

/// `[socket]`: the control socket.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct SocketConfig {
    pub path: PathBuf,
    /// File mode of the socket (octal in the file, e.g. "0660").
    pub mode: u32,
    /// Group the socket belongs to; its members may connect (None: the service user's).
    pub group: Option<String>,
    /// User ids allowed besides root, the service's own user and the group's members.
    pub allow_uids: Vec<u32>,
    /// The same API on a loopback TCP address, for show-control software (None: off).
    pub tcp: Option<std::net::SocketAddr>,
    /// The file holding the token every TCP request must carry (required with `tcp`).
    pub tcp_token_file: Option<PathBuf>,
}

/// `[http]`: the operator's console (a web page), its event stream and metrics.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct HttpConfig {
    /// Where it listens (None: off). Loopback by default; another address needs `token_file`
    /// and `allow`.
    #[serde(serialize_with = "display_or_none")]
    pub listen: Option<std::net::SocketAddr>,
    /// The file holding the token a client from another machine gives (a header, or the login
    /// page's cookie).
    pub token_file: Option<PathBuf>,
    /// Networks clients from other machines may come from (`10.0.0.0/24`); loopback always may.
    #[serde(serialize_with = "displayed_list")]
    pub allow: Vec<ipnet::IpNet>,
    /// HTTPS: the certificate chain and its private key (PEM files); both or neither.
    pub tls: Option<TlsFiles>,
}

/// A certificate chain and its private key, PEM files.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct TlsFiles {
    pub cert: PathBuf,
    pub key: PathBuf,
}

fn displayed_list<T: std::fmt::Display, S: serde::Serializer>(
    v: &[T],
    s: S,
) -> std::result::Result<S::Ok, S::Error> {
    s.collect_seq(v.iter().map(|x| x.to_string()))
}

/// `[osc]`: Open Sound Control for show-control software.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct OscConfig {
    /// The UDP address it listens on (None: off, the default).
    #[serde(serialize_with = "display_or_none")]
    pub listen: Option<std::net::SocketAddr>,
    /// Networks senders on other machines may come from; loopback always may.
    #[serde(serialize_with = "displayed_list")]
    pub allow: Vec<ipnet::IpNet>,
    /// Where the service's state and events are sent (`IP:PORT`).
    #[serde(serialize_with = "displayed_list")]
    pub peers: Vec<std::net::SocketAddr>,
}

/// The console's address unless `[http] listen` says otherwise.
pub const DEFAULT_HTTP: &str = "127.0.0.1:7421";

/// `[log]`.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct LogConfig {
    /// Seconds between two frame-count lines in the log during playback.
    pub stats_period_s: f64,
}

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

/// The state directory when the file does not name one: systemd's `$STATE_DIRECTORY` (the
/// first, when it lists several), else /var/lib/compend.
fn default_state() -> PathBuf {
    std::env::var_os("STATE_DIRECTORY")
        .and_then(|v| {
            v.to_str()
                .and_then(|s| s.split(':').next())
                .map(PathBuf::from)
        })
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or_else(|| PathBuf::from("/var/lib/compend"))
}

/// The socket when the file does not name one: in systemd's `$RUNTIME_DIRECTORY`, else
/// /run/compend/compend.sock.
fn default_socket() -> PathBuf {
    std::env::var_os("RUNTIME_DIRECTORY")
        .and_then(|v| {
            v.to_str()
                .and_then(|s| s.split(':').next())
                .map(PathBuf::from)
        })
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or_else(|| PathBuf::from("/run/compend"))
        .join("compend.sock")
}

impl Config {
    /// Every key at its default (the state and socket paths from systemd's environment when it
    /// sets them).
    pub fn defaults() -> Self {
        // Parsing an empty document yields exactly the defaults.
        match Self::parse("", Path::new("(defaults)")) {
            Ok(c) => c,
            Err(e) => unreachable_defaults(e),
        }
    }

    /// Reads and parses `path`.
    pub fn load(path: &Path) -> Result<Self> {
        let text = crate::files::read_text(path, "a compend configuration file (TOML)")?;
        Self::parse(&text, path)
    }

    /// Parses a configuration; `path` names the file in messages. Every problem is reported,
    /// one per line, in one [`Error::Input`].
    pub fn parse(text: &str, path: &Path) -> Result<Self> {
        let mut w = Walker::new(text, path);
        let config = w.document();
        match (config, w.errors.is_empty()) {
            (Some(c), true) => Ok(c),
            _ => Err(w.into_error()),
        }
    }
}

#[cold]
fn unreachable_defaults(e: Error) -> Config {
    // The defaults are constants checked by a test; reaching this is a bug in this file.
    panic!("compend's built-in configuration defaults do not parse: {e}")
}

/// Every `section.key` the parser knows, in the order it reads them.
pub fn known_keys() -> Vec<String> {
    let mut w = Walker::new("", Path::new("(keys)"));
    let _ = w.document();
    w.asked
}

/// A table being read: what is left of it, its name and where it is.
struct Table<'i> {
    name: &'static str,
    entries: Vec<(String, Range<usize>, Spanned<DeValue<'i>>)>,
}

/// The reader: collects errors and the keys it asked for.
struct Walker<'t> {
    text: &'t str,
    file: String,
    errors: Vec<(usize, String)>,
    asked: Vec<String>,
}

impl<'t> Walker<'t> {
    fn new(text: &'t str, path: &Path) -> Self {
        Self {
            text,
            file: path.display().to_string(),
            errors: Vec::new(),
            asked: Vec::new(),
        }
    }

    fn line(&self, offset: usize) -> usize {
        let end = offset.min(self.text.len());
        self.text.as_bytes()[..end]
            .iter()
            .filter(|&&b| b == b'\n')
            .count()
            + 1
    }

    fn error(&mut self, span: Range<usize>, message: String) {
        let line = self.line(span.start);
        self.errors.push((line, message));
    }

    fn into_error(mut self) -> Error {
        self.errors.sort_by_key(|(line, _)| *line);
        let n = self.errors.len();
        let lines: Vec<String> = self
            .errors
            .iter()
            .map(|(line, m)| format!("  {}:{line}: {m}", self.file))
            .collect();
        Error::Input(format!(
            "{}: {n} error{} in the configuration:\n{}",
            self.file,
            if n == 1 { "" } else { "s" },
            lines.join("\n")
        ))
    }

    /// Reads the whole document; `None` when it is not TOML at all.
    fn document(&mut self) -> Option<Config> {
        let (root, parse_errors) = DeTable::parse_recoverable(self.text);
        for e in &parse_errors {
            let span = e.span().unwrap_or(0..0);
            // What the span covers (a key given twice, a bad value), when it is short.
            let at = self
                .text
                .get(span.clone())
                .and_then(|s| s.lines().next())
                .map(str::trim)
                .filter(|s| !s.is_empty() && s.chars().count() <= 80)
                .map_or(String::new(), |s| format!(" (at `{s}`)"));
            self.error(span, format!("not valid TOML: {}{at}", e.message().trim()));
        }
        if !parse_errors.is_empty() {
            return None;
        }
        let mut root = Table {
            name: "",
            entries: entries(root.into_inner()),
        };
        let config = self.sections(&mut root);
        self.finish(root);
        Some(config)
    }

    fn sections(&mut self, root: &mut Table<'t>) -> Config {
        let mut t = self.table(root, "rig");
        let rig = self.rig(&mut t);
        self.finish(t);

        let mut t = self.table(root, "paths");
        let state: PathBuf = self.get(&mut t, "state").unwrap_or_else(default_state);
        let data = self
            .get(&mut t, "data")
            .unwrap_or_else(|| state.join("calibration"));
        let model = self
            .get(&mut t, "model")
            .unwrap_or_else(|| state.join("model"));
        let models = self
            .get(&mut t, "models")
            .unwrap_or_else(|| vec![state.clone()]);
        let paths = PathsConfig {
            state,
            data,
            model,
            models,
        };
        self.finish(t);

        let mut t = self.table(root, "calibration");
        let calibration = self.calibration(&mut t);
        self.finish(t);

        let mut t = self.table(root, "playback");
        let items = self.playlist(&mut t);
        let repeat = self.get(&mut t, "repeat").unwrap_or(true);
        let playback = PlaybackConfig {
            source: match items {
                Some(items) if items.len() > 1 || items[0].loops != 1 => {
                    crate::source::Playlist { items, repeat }
                }
                Some(mut items) => crate::source::Playlist {
                    items: vec![items.remove(0)],
                    repeat: false,
                },
                None => crate::source::Playlist::single("pattern:bars"),
            },
            autoplay: self.get(&mut t, "autoplay").unwrap_or(true),
            media: self
                .get(&mut t, "media")
                .unwrap_or_else(|| vec![paths.state.join("media")]),
        };
        self.finish(t);

        let mut t = self.table(root, "audio");
        let audio = AudioConfig {
            enabled: self.get(&mut t, "enabled").unwrap_or(true),
            device: self.checked(
                &mut t,
                "device",
                crate::media::audio::AUTO.to_string(),
                |s: &String| {
                    if s.trim().is_empty() {
                        Err("an empty sink; e.g. \"auto\" or \"alsasink device=hw:1\"".into())
                    } else {
                        Ok(())
                    }
                },
            ),
            delay_ms: self.checked(&mut t, "delay_ms", 0.0, |v: &f64| {
                if v.is_finite() && v.abs() <= 10_000.0 {
                    Ok(())
                } else {
                    Err(format!("{v} ms: expected -10000 to 10000"))
                }
            }),
        };
        self.finish(t);

        let mut t = self.table(root, "output");
        let output = OutputConfig {
            to: self.parsed_with(&mut t, "to", |s| {
                crate::output::OutputSpec::parse(s).map_err(|e| e.to_string())
            }),
        };
        self.finish(t);

        let mut t = self.table(root, "monitoring");
        let monitoring = MonitoringConfig {
            enabled: self.get(&mut t, "enabled").unwrap_or(true),
            period_s: self.positive(&mut t, "period_s", 30.0),
            drift_threshold_db: self.positive(&mut t, "drift_threshold_db", 3.0),
            on_drift: self.choice(
                &mut t,
                "on_drift",
                DriftPolicy::Recalibrate,
                &[
                    ("report", DriftPolicy::Report),
                    ("recalibrate", DriftPolicy::Recalibrate),
                    ("refit", DriftPolicy::Refit),
                ],
            ),
            refit_ntrain: self.checked(&mut t, "refit_ntrain", 8usize, |&n| {
                if n >= crate::fit::MIN_TRAIN {
                    Ok(())
                } else {
                    Err(format!(
                        "at least {} sampling images are needed",
                        crate::fit::MIN_TRAIN
                    ))
                }
            }),
        };
        self.finish(t);

        let mut t = self.table(root, "socket");
        let socket = self.socket(&mut t);
        self.finish(t);

        let mut t = self.table(root, "http");
        let http = self.http(&mut t);
        self.finish(t);

        let mut t = self.table(root, "osc");
        let osc = self.osc(&mut t);
        self.finish(t);

        let mut t = self.table(root, "log");
        let log = LogConfig {
            stats_period_s: self.positive(&mut t, "stats_period_s", 60.0),
        };
        self.finish(t);

        Config {
            rig,
            paths,
            calibration,
            playback,
            audio,
            output,
            monitoring,
            socket,
            http,
            osc,
            log,
        }
    }

    /// `[playback] source`: a source's spelling, or a list of items, each a spelling or a
    /// table `{ src = "...", loop = N, duration_s = S }`. `None` when absent or wrong
    /// (recorded, each wrong item at its line).
    fn playlist(&mut self, t: &mut Table<'t>) -> Option<Vec<crate::source::PlaylistItem>> {
        use crate::source::{PlaylistItem, SourceSpec};
        let span = span_of(t, "source");
        let value: serde_json::Value = self.get(t, "source")?;
        let mut errors = Vec::new();
        let mut item = |i: Option<usize>, v: &serde_json::Value| -> Option<PlaylistItem> {
            let at = i.map_or(String::new(), |i| format!(" item {}", i + 1));
            let mut it = match v {
                serde_json::Value::String(s) => PlaylistItem::once(s.clone()),
                serde_json::Value::Object(o) => {
                    if let Some(k) = o
                        .keys()
                        .find(|k| !["src", "loop", "duration_s"].contains(&k.as_str()))
                    {
                        errors.push(format!(
                            "[playback] source{at}: unknown key `{k}` (known: src, loop, \
                             duration_s)"
                        ));
                        return None;
                    }
                    let Some(src) = o.get("src").and_then(|s| s.as_str()) else {
                        errors.push(format!(
                            "[playback] source{at}: needs `src`, the source's spelling"
                        ));
                        return None;
                    };
                    let loops = match o.get("loop") {
                        None => 1,
                        Some(l) => match l.as_u64().filter(|&n| n <= u32::MAX as u64) {
                            Some(n) => n as u32,
                            None => {
                                errors.push(format!(
                                    "[playback] source{at}: loop must be a whole number of \
                                     passes (0: until the operator moves on), got {l}"
                                ));
                                return None;
                            }
                        },
                    };
                    let duration_s = match o.get("duration_s") {
                        None => None,
                        Some(d) => match d.as_f64().filter(|d| d.is_finite() && *d > 0.0) {
                            Some(d) => Some(d),
                            None => {
                                errors.push(format!(
                                    "[playback] source{at}: duration_s must be a positive \
                                     number of seconds, got {d}"
                                ));
                                return None;
                            }
                        },
                    };
                    PlaylistItem {
                        source: src.to_string(),
                        loops,
                        duration_s,
                    }
                }
                other => {
                    errors.push(format!(
                        "[playback] source{at}: expected a source's spelling or a table with \
                         src, got {other}"
                    ));
                    return None;
                }
            };
            if let Err(e) = SourceSpec::parse(&it.source) {
                errors.push(format!("[playback] source{at}: {e}"));
                return None;
            }
            it.source = it.source.trim().to_string();
            Some(it)
        };
        let items: Vec<Option<PlaylistItem>> = match &value {
            serde_json::Value::Array(list) if list.is_empty() => {
                errors.push("[playback] source: an empty list; give at least one item".into());
                Vec::new()
            }
            serde_json::Value::Array(list) => list
                .iter()
                .enumerate()
                .map(|(i, v)| item(Some(i), v))
                .collect(),
            v => vec![item(None, v)],
        };
        let ok = errors.is_empty();
        for e in errors {
            self.error(span.clone(), e);
        }
        ok.then(|| items.into_iter().flatten().collect())
    }

    fn rig(&mut self, t: &mut Table<'t>) -> RigConfig {
        let kind = self.choice(
            t,
            "kind",
            RigKind::Virtual,
            &[
                ("virtual", RigKind::Virtual),
                ("window", RigKind::Window),
                ("camera", RigKind::Camera),
            ],
        );
        let rig = RigConfig {
            kind,
            scene: self.get(t, "scene").unwrap_or_else(|| "curved".to_string()),
            seed: self.get(t, "seed").unwrap_or(0),
            camera: self.get(t, "camera"),
            camera_size: self.size(t, "camera_size", false),
            projector: self.size(t, "projector", false),
            monitor: self.get(t, "monitor"),
            fps: self.positive(t, "fps", 60.0),
            camera_fps: self.optional_positive(t, "camera_fps"),
            latency_ms: self.optional_non_negative(t, "latency_ms"),
            drift_after_s: self.optional_non_negative(t, "drift_after_s"),
        };
        if kind == RigKind::Camera && rig.camera.is_none() {
            self.errors.push((
                self.line(0),
                "[rig] kind = \"camera\" needs `camera`, the V4L2 device (e.g. /dev/video0)".into(),
            ));
        }
        rig
    }

    fn calibration(&mut self, t: &mut Table<'t>) -> CalibrationConfig {
        let method = self.parsed(
            t,
            "method",
            MethodChoice::Rung(crate::model::Method::Linear),
        );
        let device = self
            .parsed_with(t, "device", |s| {
                let d: crate::fit::TrainDevice =
                    s.parse().map_err(|e: crate::Error| e.to_string())?;
                if d != crate::fit::TrainDevice::Cpu && !cfg!(feature = "cuda") {
                    return Err(format!(
                        "\"{s}\": this compend was built without CUDA; rebuild it with `cargo \
                         build --release --features cuda`, or train on \"cpu\""
                    ));
                }
                Ok(d)
            })
            .unwrap_or_default();
        let ntrain_at = span_of(t, "ntrain");
        let ntrain = self.checked(
            t,
            "ntrain",
            crate::calibrate::SamplingCount::Count(crate::fit::DEFAULT_TRAIN),
            |&n| {
                if n.most() >= crate::fit::MIN_TRAIN {
                    Ok(())
                } else {
                    Err(format!(
                        "at least {} training images are needed",
                        crate::fit::MIN_TRAIN
                    ))
                }
            },
        );
        if ntrain == crate::calibrate::SamplingCount::Auto
            && let Some(p) = crate::calibrate::rounds_problem(method)
        {
            self.error(ntrain_at, format!("[calibration] ntrain = \"auto\": {p}"));
        }
        // Compared only when both were read without error (a wrong one stands at its
        // default), at the line of whichever of them the file gives (verify's first).
        let errors = self.errors.len();
        let at = match span_of(t, "verify") {
            s if s != (0..0) => s,
            _ => span_of(t, "ntest"),
        };
        let ntest = self.checked(t, "ntest", 10usize, |&n| at_least_one(n));
        let verify = self.checked(t, "verify", 5usize, |&n| at_least_one(n));
        if verify > ntest && self.errors.len() == errors {
            self.error(
                at,
                format!("[calibration] verify = {verify} is more than ntest = {ntest}"),
            );
        }
        let refresh_hz = self.checked(t, "refresh_hz", None, |v: &Option<f64>| {
            match v.and_then(crate::fit::refresh_rate_problem) {
                Some(problem) => Err(problem),
                None => Ok(()),
            }
        });
        let span = span_of(t, "loop_images");
        let loop_images: Option<usize> = self.get(t, "loop_images");
        if let Some(n) = loop_images
            && let Some(p) = crate::calibrate::loop_images_problem(method, n)
        {
            self.error(span, format!("[calibration] loop_images = {n}: {p}"));
        }
        CalibrationConfig {
            method,
            ntrain,
            ntest,
            verify,
            min_gain_db: self.checked(
                t,
                "min_gain_db",
                crate::calibrate::DEFAULT_MIN_GAIN_DB,
                |v: &f64| finite(*v),
            ),
            average: self.checked(t, "average", 3usize, |&n| at_least_one(n)),
            network: self
                .parsed_with(t, "network", |s| {
                    let n = ImageSize::parse(s, true)?;
                    if n.width % 4 == 0 && n.height % 4 == 0 {
                        Ok(n)
                    } else {
                        Err(format!(
                            "network size {n}: width and height must be divisible by 4"
                        ))
                    }
                })
                .unwrap_or(ImageSize::new(256, 256)),
            on_start: self.choice(
                t,
                "on_start",
                OnStart::IfNoModel,
                &[
                    ("if-no-model", OnStart::IfNoModel),
                    ("never", OnStart::Never),
                ],
            ),
            keep_runs: self.get(t, "keep_runs").unwrap_or(3),
            climb: self
                .parsed_with(t, "climb", |s| match s {
                    "none" => Ok(None),
                    "auto" => Ok(Some(crate::fit::climb_rung(device))),
                    rung => crate::model::Method::from_str(rung)
                        .map(Some)
                        .map_err(|e| format!("{e}; or \"auto\" or \"none\"")),
                })
                .unwrap_or(None),
            climb_gain_db: self.checked(
                t,
                "climb_gain_db",
                crate::fit::DEFAULT_RIG_GAIN_DB,
                |v: &f64| finite(*v),
            ),
            climb_iters: self.get::<usize>(t, "climb_iters").filter(|&n| n > 0),
            device,
            loop_images,
            refresh_hz,
        }
    }

    fn socket(&mut self, t: &mut Table<'t>) -> SocketConfig {
        let path = self.get(t, "path").unwrap_or_else(default_socket);
        let mode = self
            .parsed_with(t, "mode", |s: &str| {
                let digits = s.strip_prefix("0o").unwrap_or(s);
                match u32::from_str_radix(digits, 8) {
                    Ok(m) if m <= 0o777 => Ok(m),
                    _ => Err(format!(
                        "\"{s}\" is not a file mode; expected octal digits such as \"0660\""
                    )),
                }
            })
            .unwrap_or(0o660);
        let group = self.get(t, "group");
        let allow_uids = self.get(t, "allow_uids").unwrap_or_default();
        let tcp_span = span_of(t, "tcp");
        let has_tcp = t.entries.iter().any(|(k, _, _)| k == "tcp");
        let tcp = self.parsed_with(t, "tcp", |s: &str| {
            let addr: std::net::SocketAddr = s.parse().map_err(|_| {
                format!("\"{s}\" is not an address; expected IP:PORT such as \"127.0.0.1:7420\"")
            })?;
            if !addr.ip().is_loopback() {
                return Err(format!(
                    "\"{s}\" is not a loopback address: the TCP API listens on this machine \
                     only (127.0.0.1 or [::1])"
                ));
            }
            Ok(addr)
        });
        let tcp_token_file: Option<PathBuf> = self.get(t, "tcp_token_file");
        if has_tcp && tcp_token_file.is_none() {
            self.error(
                tcp_span,
                "[socket] tcp needs tcp_token_file, a file holding the token every TCP request \
                 carries"
                    .into(),
            );
        }
        SocketConfig {
            path,
            mode,
            group,
            allow_uids,
            tcp,
            tcp_token_file,
        }
    }

    fn http(&mut self, t: &mut Table<'t>) -> HttpConfig {
        let listen_span = span_of(t, "listen");
        let listen = self
            .parsed_with(t, "listen", |s: &str| {
                if s == "off" {
                    return Ok(None);
                }
                s.parse::<std::net::SocketAddr>().map(Some).map_err(|_| {
                    format!(
                        "\"{s}\" is not an address; expected IP:PORT such as \"{DEFAULT_HTTP}\", \
                         or \"off\""
                    )
                })
            })
            .unwrap_or_else(|| DEFAULT_HTTP.parse().ok());
        let token_file: Option<PathBuf> = self.get(t, "token_file");
        let nets = self.networks(t);
        if let Some(addr) = listen
            && !addr.ip().is_loopback()
        {
            if token_file.is_none() {
                self.error(
                    listen_span.clone(),
                    format!(
                        "[http] listen = \"{addr}\" is reachable from other machines: it needs \
                         token_file, a file holding the token their requests carry"
                    ),
                );
            }
            if nets.is_empty() {
                self.error(
                    listen_span,
                    format!(
                        "[http] listen = \"{addr}\" is reachable from other machines: it needs \
                         allow, the networks they may come from (e.g. [\"10.0.0.0/24\"])"
                    ),
                );
            }
        }
        let cert_span = span_of(t, "tls_cert");
        let cert: Option<PathBuf> = self.get(t, "tls_cert");
        let key_span = span_of(t, "tls_key");
        let key: Option<PathBuf> = self.get(t, "tls_key");
        let tls = match (cert, key) {
            (Some(cert), Some(key)) => Some(TlsFiles { cert, key }),
            (None, None) => None,
            (Some(_), None) => {
                self.error(
                    cert_span,
                    "[http] tls_cert needs tls_key, the certificate's private key".into(),
                );
                None
            }
            (None, Some(_)) => {
                self.error(
                    key_span,
                    "[http] tls_key needs tls_cert, the certificate chain it signs for".into(),
                );
                None
            }
        };
        HttpConfig {
            listen,
            token_file,
            allow: nets,
            tls,
        }
    }

    /// `allow`: networks (`10.0.0.0/24`) or single addresses.
    fn networks(&mut self, t: &mut Table<'t>) -> Vec<ipnet::IpNet> {
        let span = span_of(t, "allow");
        let allow: Vec<String> = self.get(t, "allow").unwrap_or_default();
        let mut nets = Vec::new();
        for a in &allow {
            match a
                .parse::<ipnet::IpNet>()
                .or_else(|_| a.parse::<std::net::IpAddr>().map(ipnet::IpNet::from))
            {
                Ok(n) => nets.push(n),
                Err(_) => self.error(
                    span.clone(),
                    format!(
                        "[{}] allow: \"{a}\" is not a network; expected an address or \
                         ADDRESS/BITS such as \"10.0.0.0/24\"",
                        t.name
                    ),
                ),
            }
        }
        nets
    }

    fn osc(&mut self, t: &mut Table<'t>) -> OscConfig {
        let listen_span = span_of(t, "listen");
        let listen = self.parsed_with(t, "listen", |s: &str| {
            s.parse::<std::net::SocketAddr>().map_err(|_| {
                format!("\"{s}\" is not an address; expected IP:PORT such as \"127.0.0.1:7422\"")
            })
        });
        let allow = self.networks(t);
        let peers_span = span_of(t, "peers");
        let peers: Vec<String> = self.get(t, "peers").unwrap_or_default();
        let mut addrs = Vec::new();
        for p in &peers {
            match p.parse::<std::net::SocketAddr>() {
                Ok(a) => addrs.push(a),
                Err(_) => self.error(
                    peers_span.clone(),
                    format!(
                        "[osc] peers: \"{p}\" is not an address; expected IP:PORT such as \
                         \"10.0.0.9:53000\""
                    ),
                ),
            }
        }
        if let Some(addr) = listen
            && !addr.ip().is_loopback()
            && allow.is_empty()
        {
            self.error(
                listen_span,
                format!(
                    "[osc] listen = \"{addr}\" is reachable from other machines: it needs allow, \
                     the networks senders may come from (e.g. [\"10.0.0.0/24\"]); OSC carries no \
                     token"
                ),
            );
        }
        OscConfig {
            listen,
            allow,
            peers: addrs,
        }
    }

    /// Takes section `name` out of `root`; a missing one is empty.
    fn table(&mut self, root: &mut Table<'t>, name: &'static str) -> Table<'t> {
        let empty = Table {
            name,
            entries: Vec::new(),
        };
        let Some(i) = root.entries.iter().position(|(k, _, _)| k == name) else {
            return empty;
        };
        let (_, span, value) = root.entries.remove(i);
        match value.into_inner() {
            DeValue::Table(t) => Table {
                name,
                entries: entries(t),
            },
            other => {
                self.error(
                    span,
                    format!(
                        "`{name}` must be a section ([{name}]), not {}",
                        with_article(other.type_str())
                    ),
                );
                empty
            }
        }
    }

    /// Takes `key` out of `t` and deserialises it; `None` when absent or wrong (recorded).
    fn get<T: DeserializeOwned>(&mut self, t: &mut Table<'t>, key: &str) -> Option<T> {
        self.asked.push(format!("{}.{key}", t.name));
        let i = t.entries.iter().position(|(k, _, _)| k == key)?;
        let (_, _, value) = t.entries.remove(i);
        let span = value.span();
        let type_name = with_article(value.get_ref().type_str());
        match T::deserialize(ValueDeserializer::from(value)) {
            Ok(v) => Some(v),
            Err(e) => {
                let what = std::any::type_name::<T>();
                self.error(
                    span,
                    format!(
                        "[{}] {key}: {} (expected {}, got {type_name})",
                        t.name,
                        e.message().trim(),
                        expected_name(what)
                    ),
                );
                None
            }
        }
    }

    /// `key` with `check`, else `default` (a failed check is recorded).
    fn checked<T: DeserializeOwned>(
        &mut self,
        t: &mut Table<'t>,
        key: &str,
        default: T,
        check: impl FnOnce(&T) -> std::result::Result<(), String>,
    ) -> T {
        let span = span_of(t, key);
        match self.get::<T>(t, key) {
            None => default,
            Some(v) => match check(&v) {
                Ok(()) => v,
                Err(m) => {
                    self.error(span, format!("[{}] {key}: {m}", t.name));
                    default
                }
            },
        }
    }

    /// A string parsed by `parse`; `None` when absent or wrong (recorded).
    fn parsed_with<T>(
        &mut self,
        t: &mut Table<'t>,
        key: &str,
        parse: impl FnOnce(&str) -> std::result::Result<T, String>,
    ) -> Option<T> {
        let span = span_of(t, key);
        let s: String = self.get(t, key)?;
        match parse(&s) {
            Ok(v) => Some(v),
            Err(m) => {
                self.error(span, format!("[{}] {key}: {m}", t.name));
                None
            }
        }
    }

    fn parsed<T: FromStr>(&mut self, t: &mut Table<'t>, key: &str, default: T) -> T
    where
        T::Err: std::fmt::Display,
    {
        self.parsed_with(t, key, |s| T::from_str(s).map_err(|e| e.to_string()))
            .unwrap_or(default)
    }

    fn choice<T: Copy>(
        &mut self,
        t: &mut Table<'t>,
        key: &str,
        default: T,
        options: &[(&str, T)],
    ) -> T {
        self.parsed_with(t, key, |s| {
            options
                .iter()
                .find(|(name, _)| *name == s)
                .map(|(_, v)| *v)
                .ok_or_else(|| {
                    let names: Vec<String> =
                        options.iter().map(|(n, _)| format!("\"{n}\"")).collect();
                    format!("\"{s}\" is not one of {}", names.join(", "))
                })
        })
        .unwrap_or(default)
    }

    fn size(&mut self, t: &mut Table<'t>, key: &str, square_ok: bool) -> Option<ImageSize> {
        self.parsed_with(t, key, |s| ImageSize::parse(s, square_ok))
    }

    fn positive(&mut self, t: &mut Table<'t>, key: &str, default: f64) -> f64 {
        self.optional_positive(t, key).unwrap_or(default)
    }

    fn optional_positive(&mut self, t: &mut Table<'t>, key: &str) -> Option<f64> {
        let span = span_of(t, key);
        let v: f64 = self.get(t, key)?;
        if v.is_finite() && v > 0.0 && v <= LARGEST {
            Some(v)
        } else {
            self.error(
                span,
                format!(
                    "[{}] {key}: {v} must be a positive number, at most {LARGEST:e}",
                    t.name
                ),
            );
            None
        }
    }

    fn optional_non_negative(&mut self, t: &mut Table<'t>, key: &str) -> Option<f64> {
        let span = span_of(t, key);
        let v: f64 = self.get(t, key)?;
        if v.is_finite() && (0.0..=LARGEST).contains(&v) {
            Some(v)
        } else {
            self.error(
                span,
                format!(
                    "[{}] {key}: {v} must be zero or more, at most {LARGEST:e}",
                    t.name
                ),
            );
            None
        }
    }

    /// Whatever is left in `t` is unknown.
    fn finish(&mut self, t: Table<'t>) {
        let prefix = if t.name.is_empty() {
            String::new()
        } else {
            format!("{}.", t.name)
        };
        let known: Vec<String> = self
            .asked
            .iter()
            .filter_map(|k| k.strip_prefix(&prefix))
            .filter(|k| !k.contains('.') || prefix.is_empty())
            .map(str::to_string)
            .collect();
        for (key, span, _) in t.entries {
            let place = if t.name.is_empty() {
                "top level".to_string()
            } else {
                format!("[{}]", t.name)
            };
            let known_here: Vec<&str> = if t.name.is_empty() {
                SECTIONS.to_vec()
            } else {
                known.iter().map(String::as_str).collect()
            };
            let hint = nearest(&key, &known_here)
                .map(|k| format!("; did you mean `{k}`?"))
                .unwrap_or_else(|| format!("; known: {}", known_here.join(", ")));
            self.error(span, format!("unknown key `{key}` at the {place}{hint}"));
        }
    }
}

/// The sections, in the order of the shipped file.
const SECTIONS: [&str; 11] = [
    "rig",
    "paths",
    "calibration",
    "playback",
    "audio",
    "output",
    "monitoring",
    "socket",
    "http",
    "osc",
    "log",
];

fn entries(t: DeTable<'_>) -> Vec<(String, Range<usize>, Spanned<DeValue<'_>>)> {
    t.into_iter()
        .map(|(k, v)| {
            let span = k.span();
            (k.into_inner().into_owned(), span, v)
        })
        .collect()
}

fn span_of(t: &Table<'_>, key: &str) -> Range<usize> {
    t.entries
        .iter()
        .find(|(k, _, _)| k == key)
        .map_or(0..0, |(_, _, v)| v.span())
}

fn at_least_one(n: usize) -> std::result::Result<(), String> {
    if n >= 1 {
        Ok(())
    } else {
        Err("must be at least 1".into())
    }
}

fn finite(v: f64) -> std::result::Result<(), String> {
    if v.is_finite() {
        Ok(())
    } else {
        Err(format!("{v} is not a number of dB"))
    }
}

/// What a Rust type is called in a TOML file.
fn expected_name(type_name: &str) -> &'static str {
    match type_name {
        t if t.contains("SamplingCount") => "a whole number or \"auto\"",
        t if t.contains("PathBuf") => "a path string",
        t if t.contains("String") => "a string",
        "bool" => "true or false",
        "f64" | "f32" => "a number",
        "u64" | "u32" | "usize" => "a whole number",
        t if t.contains("Vec<u32>") => "a list of whole numbers",
        _ => "another type",
    }
}

/// The known key closest to `key` by edit distance (insertions, deletions, substitutions and
/// swaps of two neighbouring characters: a typed `sede` is one edit from `seed`, two from
/// `scene`), when it is close.
fn nearest<'a>(key: &str, known: &[&'a str]) -> Option<&'a str> {
    known
        .iter()
        .map(|k| (strsim::osa_distance(key, k), *k))
        .filter(|(d, k)| *d <= 2.max(k.len() / 3))
        .min_by_key(|(d, _)| *d)
        .map(|(_, k)| k)
}

/// A TOML type's name with its article: "an integer", "a string".
fn with_article(name: &str) -> String {
    let article = if name.starts_with(['a', 'e', 'i', 'o', 'u']) {
        "an"
    } else {
        "a"
    };
    format!("{article} {name}")
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str) -> Result<Config> {
        Config::parse(text, Path::new("t.toml"))
    }

    #[test]
    fn an_empty_file_is_the_defaults() {
        let c = parse("").unwrap();
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
    fn known_keys_cover_every_section() {
        let keys = known_keys();
        for s in SECTIONS {
            assert!(keys.iter().any(|k| k.starts_with(&format!("{s}."))), "{s}");
        }
        assert!(keys.contains(&"monitoring.on_drift".to_string()));
    }
}
