//! The control protocol: one JSON request per line in, one JSON reply per line out, on the
//! service's Unix socket. Pure types and parsing; the socket is [`super::socket`].
//!
//! Requests (`cmd` names the request; unknown fields are refused):
//!
//! ```text
//! {"cmd":"status"}                          the state, model, source, frame counts, monitoring
//! {"cmd":"calibrate"}  {"cmd":"recalibrate"} calibrate now (resuming captures on disk)
//! {"cmd":"refit"}                           a fast calibration in a new run: the linear rung
//!                                           from [monitoring] refit_ntrain sampling images
//! {"cmd":"play"}  {"cmd":"play","source":"pattern:bars"}
//!                                           play the configured source, or this one
//! {"cmd":"pause"}                           a film or stream: pause it (its frame stays);
//!                                           anything else: stop playing (black)
//! {"cmd":"seek","position_s":12.5}          a film: go to this time from its start
//! {"cmd":"next"}  {"cmd":"previous"}        a playlist: the next or previous item
//! {"cmd":"model","path":"/var/lib/compend/other-model"}
//!                                           load and play another model directory
//! {"cmd":"stop"}                            shut the service down (exit 0)
//! ```
//!
//! Every reply has `ok`; a failed request has `error`, a status request `status`, others a
//! `message` saying what happens now.

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

use crate::model::Model;
use crate::record::{ClimbRecord, Verification};

/// The longest request line taken, bytes; a longer one gets an error reply and is skipped.
pub const MAX_REQUEST_BYTES: usize = 64 * 1024;

/// The longest `path` or `source` a request may carry, bytes: Linux's PATH_MAX (4096, its
/// terminating NUL included) less one. A longer one names no file: refused at parsing, so that
/// it is neither tried nor written to the log.
pub const MAX_PATH_BYTES: usize = 4095;

/// Whether a client may ask the service to play `source`: anything `compend play` takes except
/// a `gst:` pipeline, which can run any GStreamer element (a `filesink` writes any file the
/// service's user may write). Pipelines are for the configuration (`[playback] source`), which
/// only its owner edits.
pub fn check_requested_source(source: &str) -> Result<(), String> {
    if source.trim_start().starts_with("gst:") {
        return Err(
            "a gst: pipeline is not taken from a client (it can run any GStreamer element and \
             write files as the service); put it in [playback] source of the configuration"
                .into(),
        );
    }
    Ok(())
}

/// A request.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "cmd", rename_all = "lowercase", deny_unknown_fields)]
pub enum Request {
    Status,
    Calibrate,
    Recalibrate,
    /// A fast calibration in a new run: the `linear` rung from `[monitoring] refit_ntrain`
    /// sampling images, as drift's `on_drift = "refit"` runs it.
    Refit,
    Play {
        #[serde(default, skip_serializing_if = "Option::is_none")]
        source: Option<String>,
    },
    Pause,
    Seek {
        position_s: f64,
    },
    Next,
    Previous,
    Model {
        path: PathBuf,
    },
    /// The setup view: a test pattern projected as it is, the camera watched at its full rate.
    Setup {
        #[serde(default, skip_serializing_if = "Option::is_none")]
        pattern: Option<String>,
    },
    Stop,
}

/// A JSON object whose keys are each given once (its values are not looked at).
struct UniqueKeys;

/// Whether `line`, a JSON object, gives each of its keys once: the error names the first key
/// given twice. Checked on the raw line before anything reads a key from it (the TCP port's
/// token, a request's fields), since a parsed JSON value keeps only the last of a key given twice.
pub fn unique_keys(line: &[u8]) -> Result<(), String> {
    serde_json::from_slice::<UniqueKeys>(line)
        .map(|_| ())
        .map_err(|e| format!("bad request: {e}"))
}

impl<'de> serde::Deserialize<'de> for UniqueKeys {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct Keys;
        impl<'de> serde::de::Visitor<'de> for Keys {
            type Value = UniqueKeys;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("a JSON object")
            }
            fn visit_map<A: serde::de::MapAccess<'de>>(
                self,
                mut map: A,
            ) -> Result<UniqueKeys, A::Error> {
                let mut seen = std::collections::HashSet::new();
                while let Some(key) = map.next_key::<String>()? {
                    map.next_value::<serde::de::IgnoredAny>()?;
                    if !seen.insert(key.clone()) {
                        return Err(serde::de::Error::custom(format!(
                            "the field `{key}` is given twice"
                        )));
                    }
                }
                Ok(UniqueKeys)
            }
        }
        d.deserialize_map(Keys)
    }
}

impl Request {
    /// Parses one request line (without its newline). The error says what was wrong and what
    /// is expected, for the reply.
    pub fn parse(line: &[u8]) -> Result<Self, String> {
        Self::parse_with_id(line).0
    }

    /// [`Request::parse`], and the request's `request_id` (any request may carry one: a
    /// number, or a string of at most 64 bytes), which the reply echoes whether the request
    /// was good or not; None when absent or unreadable.
    pub fn parse_with_id(line: &[u8]) -> (Result<Self, String>, Option<serde_json::Value>) {
        const EXPECTED: &str = "expected a JSON object with \"cmd\": one of status, \
                                calibrate, recalibrate, refit, play, pause, seek, next, previous, \
                                model, setup, stop";
        let text = match std::str::from_utf8(line) {
            Ok(t) => t.trim(),
            Err(e) => {
                let e = format!("the request is not UTF-8 text (byte {})", e.valid_up_to());
                return (Err(e), None);
            }
        };
        if text.is_empty() {
            let e = "empty request; expected a JSON object such as {\"cmd\":\"status\"}";
            return (Err(e.into()), None);
        }
        let value: serde_json::Value = match serde_json::from_str(text) {
            Ok(v) => v,
            Err(e) => return (Err(format!("bad request: {e}; {EXPECTED}")), None),
        };
        let id = value.get("request_id").cloned();
        let id_ok =
            |v: &serde_json::Value| v.is_number() || v.as_str().is_some_and(|s| s.len() <= 64);
        let result = match &id {
            Some(v) if !id_ok(v) => Err(
                "bad request: `request_id` must be a number or a string of at most 64 bytes".into(),
            ),
            _ => Self::from_value(text, value, EXPECTED),
        };
        (result, id.filter(id_ok))
    }

    /// The request in `value`, parsed from `text` (a JSON value already).
    fn from_value(text: &str, value: serde_json::Value, expected: &str) -> Result<Self, String> {
        // A JSON value keeps the last of a key given twice, so `{"cmd":"status","cmd":"stop"}`
        // would stop the service: a key given twice is refused.
        if value.is_object() {
            unique_keys(text.as_bytes())?;
        }
        // serde ignores `deny_unknown_fields` on the unit variants of an internally tagged
        // enum, so the fields each request may carry are checked here.
        if let Some(object) = value.as_object()
            && let Some(cmd) = object.get("cmd").and_then(|c| c.as_str())
        {
            let allowed: &[&str] = match cmd {
                "play" => &["cmd", "source"],
                "model" => &["cmd", "path"],
                "seek" => &["cmd", "position_s"],
                "setup" => &["cmd", "pattern"],
                _ => &["cmd"],
            };
            if let Some(extra) = object
                .keys()
                .find(|k| !allowed.contains(&k.as_str()) && *k != "request_id")
            {
                return Err(format!(
                    "bad request: unknown field `{extra}` for \"{cmd}\"; it takes {}",
                    match allowed {
                        [_] => "no fields besides cmd".to_string(),
                        more => format!("`{}`", more[1..].join("`, `")),
                    }
                ));
            }
        }
        let mut value = value;
        if let Some(o) = value.as_object_mut() {
            o.remove("request_id");
        }
        let request: Self =
            serde_json::from_value(value).map_err(|e| format!("bad request: {e}; {expected}"))?;
        if let Request::Setup { pattern: Some(p) } = &request
            && let Err(e) = p.parse::<crate::patterns::SetupPattern>()
        {
            return Err(format!("bad request: {e}"));
        }
        if let Request::Seek { position_s } = &request
            && !(position_s.is_finite() && *position_s >= 0.0)
        {
            return Err(format!(
                "bad request: `position_s` is {position_s}; expected seconds from the start, 0 \
                 or more"
            ));
        }
        let (field, len) = match &request {
            Request::Model { path } => ("path", path.as_os_str().len()),
            Request::Play { source: Some(s) } => ("source", s.len()),
            _ => return Ok(request),
        };
        if len > MAX_PATH_BYTES {
            return Err(format!(
                "bad request: `{field}` is {len} bytes long; at most {MAX_PATH_BYTES} (a path \
                 on this system is shorter than 4096 bytes)"
            ));
        }
        Ok(request)
    }
}

/// The service's states.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum State {
    /// Started, nothing to play (no model, or paused before anything played).
    Idle,
    /// Measuring latency and exposure, projecting and capturing patterns.
    Calibrating,
    /// Fitting the model on the captures.
    Training,
    /// Projecting held-out test images compensated and uncompensated, scoring them.
    Verifying,
    /// The setup view: a test pattern up, the camera watched for aim, focus and exposure.
    Setup,
    /// Playing the source through the model.
    Playing,
    /// Asked to pause; the projector shows black.
    Paused,
    /// Shutting down.
    Stopping,
}

impl State {
    pub fn name(self) -> &'static str {
        match self {
            State::Idle => "idle",
            State::Calibrating => "calibrating",
            State::Training => "training",
            State::Verifying => "verifying",
            State::Setup => "setup",
            State::Playing => "playing",
            State::Paused => "paused",
            State::Stopping => "stopping",
        }
    }
}

/// The model being served.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ModelStatus {
    pub path: PathBuf,
    pub method: String,
    /// Its verification figures, when `compend calibrate` (or the service) made it.
    pub verification: Option<Verification>,
    /// Set when progressive calibration climbed to it: its held-out figures against the model
    /// it replaced.
    #[serde(default)]
    pub climb: Option<ClimbRecord>,
    /// The share of the displayable area no model can compensate, and why, as its calibration
    /// found it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub unreachable: Option<crate::fov::ReachSummary>,
    /// The captures it was trained on (their `cam/unreachable.png` shows where).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub setup: Option<PathBuf>,
    /// When the service began serving it, seconds since the Unix epoch.
    #[serde(default)]
    pub since_unix_s: f64,
    /// Why it is served: installed when the service started, by a calibration or a refit, by
    /// progressive calibration's climb, or swapped in by a request.
    #[serde(default)]
    pub why: String,
    /// A set of projectors' model: how the whole set verified (each projector's own figures
    /// are in the status's `projectors`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub set: Option<crate::record::SetVerification>,
}

/// One projector of a set, in the status.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ProjectorStatus {
    /// Its output: the monitor's name, or the virtual rig's projector.
    pub output: String,
    /// Its size, projector pixels (`800x600`).
    pub size: String,
    /// Its own calibration's verification (with the others black), when the served set's
    /// model has one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub verification: Option<Verification>,
}

impl ModelStatus {
    /// The status of `model`, served from `path` from now on; `why`: for people.
    pub fn of(path: &std::path::Path, model: &Model, why: String) -> Self {
        Self {
            path: path.to_path_buf(),
            method: model.meta.method.name().to_string(),
            verification: model
                .meta
                .calibration
                .as_ref()
                .map(|c| c.verification.clone()),
            climb: model
                .meta
                .calibration
                .as_ref()
                .and_then(|c| c.climb.clone()),
            unreachable: model
                .meta
                .calibration
                .as_ref()
                .and_then(|c| c.unreachable.clone()),
            setup: model.meta.training.setup.clone(),
            since_unix_s: now_unix_s(),
            why,
            set: None,
        }
    }

    /// The status of a set's `model`, served from `path` from now on; `why`: for people.
    pub fn of_set(
        path: &std::path::Path,
        model: &crate::model::set::SetModel,
        why: String,
    ) -> Self {
        Self {
            path: path.to_path_buf(),
            method: format!(
                "{} (a set of {}, joint)",
                crate::model::Method::Linear.name(),
                model.models.len()
            ),
            verification: None,
            climb: None,
            unreachable: None,
            setup: None,
            since_unix_s: now_unix_s(),
            why,
            set: model
                .meta
                .calibration
                .as_ref()
                .map(|c| c.verification.clone()),
        }
    }
}

/// Now, seconds since the Unix epoch (0 on a clock set before it): the time stamps of the
/// status and the events.
pub fn now_unix_s() -> f64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0.0, |d| d.as_secs_f64())
}

/// Frame counts of the current (or last) playback.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Frames {
    pub refreshes: u64,
    pub shown: u64,
    pub held: u64,
    pub dropped_source: u64,
    pub dropped_pipeline: u64,
    /// Over every playback since the service started.
    pub shown_total: u64,
    pub dropped_total: u64,
}

/// The last monitoring figures.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Monitoring {
    /// Monitoring captures scored since the model started playing.
    pub checks: u64,
    /// PSNR of the last one in the displayable area against the view it should give, dB.
    pub psnr: Option<f64>,
    pub ssim: Option<f64>,
    /// The first score of this model's playback: what drift is measured against, dB.
    pub baseline_psnr: Option<f64>,
    /// A set of projectors whose pictures overlap: the last check's seam figure (the error in
    /// a band along the overlap edges over the error away from them; above the set's limit, a
    /// seam shows).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub seam_ratio: Option<f64>,
    /// The first check's seam ratio in this playback: the figure depends on the content (its
    /// own edges may lie along an overlap), so a seam that appears is one that rises past the
    /// limit from under it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub seam_baseline: Option<f64>,
    /// A set of projectors: the last check's PSNR in each projector's own part of the area (where
    /// it lights), dB, in the set's order; `null` for a part it does not light.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub projectors_psnr: Vec<Option<f64>>,
    /// Seconds since the last check.
    pub age_s: Option<f64>,
    /// The last check fell more than the threshold below the baseline.
    pub drift: bool,
    /// Drift detections since the service started.
    pub drifts: u64,
    /// Checks since the service started whose frame the camera never saw alone (the content
    /// changed, or frames were dropped, within the projector-to-camera latency).
    #[serde(default)]
    pub unseen: u64,
}

impl Monitoring {
    /// Monitoring for a new model: no scores yet; the drift count is the service's.
    pub fn fresh(old: &Monitoring) -> Self {
        Self {
            drifts: old.drifts,
            unseen: old.unseen,
            ..Self::default()
        }
    }
}

/// Progress of a calibration.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct CalibrationProgress {
    pub phase: String,
    pub done: usize,
    pub total: usize,
    pub seconds: f64,
}

/// How a calibration ended.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CalibrationOutcome {
    /// Its model verified and was installed.
    pub installed: bool,
    /// What happened, for the operator.
    pub message: String,
}

/// How the last progressive climb ended (`[calibration] climb`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ClimbOutcome {
    /// The rung climbed to.
    pub method: String,
    /// It was installed (and plays).
    pub installed: bool,
    /// What happened, for the operator: installed, kept the model below and by how much, not
    /// climbed to (its live pass over the frame budget), failed.
    pub message: String,
}

/// The setup view: what the camera sees of a test pattern.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SetupStatus {
    /// The pattern up: grid, crosshair, white or black.
    pub pattern: String,
    /// Camera frames looked at so far.
    pub frames: u64,
    /// How sharp the last frame is ([`crate::metrics::sharpness`]): turn the focus ring for the
    /// largest.
    pub sharpness: f64,
    /// Its pixels with a channel at full scale, percent: above a few, shorten the exposure.
    pub clipped_pct: f64,
    /// Its pixels black in every channel, percent.
    pub crushed_pct: f64,
}

/// What `status` answers.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Status {
    pub state: State,
    pub version: String,
    pub pid: u32,
    pub uptime_s: f64,
    /// `virtual:curved`, `camera:/dev/video0`.
    pub rig: String,
    pub model: Option<ModelStatus>,
    /// What is playing (or was last).
    pub source: Option<String>,
    /// A media source's position, length, playlist item, sound and problems.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub media: Option<crate::media::MediaStatus>,
    pub frames: Frames,
    pub monitoring: Monitoring,
    pub calibration: Option<CalibrationProgress>,
    /// Calibrations finished (installed or not) since the service started.
    pub calibrations: u64,
    /// How the last of them ended.
    #[serde(default)]
    pub last_calibration: Option<CalibrationOutcome>,
    /// How the last progressive climb ended, since the service started.
    #[serde(default)]
    pub last_climb: Option<ClimbOutcome>,
    /// The last thing that went wrong, for the operator.
    pub last_error: Option<String>,
    /// The console's address (`[http] listen`, the port chosen when it was 0); None: off.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub http: Option<String>,
    /// The setup view's figures, while it is up.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub setup: Option<SetupStatus>,
    /// The OSC port (`[osc] listen`, the port chosen when it was 0); None: off.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub osc: Option<String>,
    /// A set of projectors: each projector's output, in the set's order (empty for one
    /// projector).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub projectors: Vec<ProjectorStatus>,
}

/// A reply.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Reply {
    pub ok: bool,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub message: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub status: Option<Box<Status>>,
    /// The request's `request_id`, echoed (a number or a string the client chose).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub request_id: Option<serde_json::Value>,
}

impl Reply {
    pub fn ok(message: impl Into<String>) -> Self {
        Self {
            ok: true,
            error: None,
            message: Some(message.into()),
            status: None,
            request_id: None,
        }
    }

    pub fn error(error: impl Into<String>) -> Self {
        Self {
            ok: false,
            error: Some(error.into()),
            message: None,
            status: None,
            request_id: None,
        }
    }

    pub fn status(status: Status) -> Self {
        Self {
            ok: true,
            error: None,
            message: None,
            status: Some(Box::new(status)),
            request_id: None,
        }
    }

    /// The reply as one line, newline included.
    pub fn to_line(&self) -> String {
        let mut s = serde_json::to_string(self).unwrap_or_else(|e| {
            format!("{{\"ok\":false,\"error\":\"cannot encode the reply: {e}\"}}")
        });
        s.push('\n');
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn requests_parse_and_bad_ones_say_why() {
        assert_eq!(Request::parse(br#"{"cmd":"status"}"#), Ok(Request::Status));
        assert_eq!(
            Request::parse(br#" {"cmd":"play","source":"pattern:bars"} "#),
            Ok(Request::Play {
                source: Some("pattern:bars".into())
            })
        );
        assert_eq!(
            Request::parse(br#"{"cmd":"play"}"#),
            Ok(Request::Play { source: None })
        );
        // A path or source as long as the system allows is taken; one byte more is refused,
        // naming the field and its length.
        let long = |field: &str, cmd: &str, n: usize| {
            format!(r#"{{"cmd":"{cmd}","{field}":"/{}"}}"#, "a".repeat(n - 1)).into_bytes()
        };
        assert!(Request::parse(&long("path", "model", MAX_PATH_BYTES)).is_ok());
        assert!(Request::parse(&long("source", "play", MAX_PATH_BYTES)).is_ok());
        for (field, cmd) in [("path", "model"), ("source", "play")] {
            let e = Request::parse(&long(field, cmd, MAX_PATH_BYTES + 1)).unwrap_err();
            assert!(
                e.contains(&format!("`{field}` is 4096 bytes long; at most 4095")),
                "{e}"
            );
        }
        let e = Request::parse(br#"{"cmd":"status","cmd":"stop"}"#).unwrap_err();
        assert!(e.contains("the field `cmd` is given twice"), "{e}");
        for bad in [
            &b""[..],
            b"status",
            b"{\"cmd\":\"reboot\"}",
            b"{\"cmd\":\"status\",\"x\":1}",
            b"{\"cmd\":\"model\"}",
            b"\xff\xfe",
            b"[1,2]",
        ] {
            let e = Request::parse(bad).unwrap_err();
            assert!(!e.is_empty());
        }
    }

    #[test]
    fn a_request_id_is_taken_out_and_given_back_even_for_a_bad_request() {
        let (r, id) = Request::parse_with_id(br#"{"cmd":"pause","request_id":7}"#);
        assert_eq!(r, Ok(Request::Pause));
        assert_eq!(id, Some(serde_json::json!(7)));
        let (r, id) = Request::parse_with_id(br#"{"cmd":"dance","request_id":"a-1"}"#);
        assert!(r.is_err());
        assert_eq!(id, Some(serde_json::json!("a-1")));
        let (r, id) = Request::parse_with_id(br#"{"cmd":"pause","request_id":[1]}"#);
        assert!(r.unwrap_err().contains("request_id"));
        assert_eq!(id, None);
        let (r, _) = Request::parse_with_id(br#"{"cmd":"pause","request_id":1,"request_id":2}"#);
        assert!(r.unwrap_err().contains("given twice"));
        let mut reply = Reply::ok("paused");
        reply.request_id = Some(serde_json::json!(7));
        assert!(reply.to_line().contains("\"request_id\":7"));
    }

    #[test]
    fn replies_are_one_line() {
        let line = Reply::error("a\nb").to_line();
        assert_eq!(line.matches('\n').count(), 1);
        let back: Reply = serde_json::from_str(line.trim()).unwrap();
        assert_eq!(back.error.as_deref(), Some("a\nb"));
    }
}
