//! `compend serve` on the virtual rig, driven only through its control socket and its clients,
//! as systemd and an operator would: it calibrates by itself, installs and plays; malformed
//! requests get errors and it keeps answering; `stop`, SIGTERM end it with exit 0; a kill -9 in
//! the middle of a recalibration leaves the previous model in place and the restarted service
//! resumes the run from the captures on disk; drift on the rig is detected by monitoring and
//! refitted from a handful of captures; a bad configuration, a busy socket and a path that is not a socket exit 2.

use std::io::{BufRead, BufReader, Write};
use std::os::unix::net::UnixStream;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use serde_json::Value;

use crate::common::{assert_code, compend, stderr, stdout};

/// A configuration for tiny sizes: a calibration takes seconds in the test profile.
pub(crate) fn write_config(
    dir: &Path,
    scene: &str,
    seed: u64,
    rig: &str,
    monitoring: &str,
) -> PathBuf {
    let state = dir.join("state");
    let socket = dir.join("compend.sock");
    let text = format!(
        r#"
[rig]
kind = "virtual"
scene = "{scene}"
seed = {seed}
camera_size = "160x120"
projector = "200x150"
fps = 30.0
{rig}

[paths]
state = "{state}"
models = ["{dir}"]

[calibration]
ntrain = 12
ntest = 4
verify = 3
network = "64"

[playback]
media = ["{dir}"]
source = "pattern:bars?size=200x150&fps=30"

[monitoring]
period_s = 0.5
{monitoring}

[socket]
path = "{socket}"

[http]
listen = "127.0.0.1:0"

[log]
stats_period_s = 2.0
"#,
        state = state.display(),
        socket = socket.display(),
        dir = dir.display()
    );
    let path = dir.join("compend.toml");
    std::fs::write(&path, text).unwrap();
    path
}

/// A running `compend serve`; killed (and its log printed) if the test ends without stopping it.
pub(crate) struct Service {
    child: Option<Child>,
    pub(crate) socket: PathBuf,
    log: PathBuf,
}

impl Service {
    pub(crate) fn start(config: &Path) -> Self {
        Self::start_on(config, None)
    }

    /// `compend serve` whose stderr is `/dev/full`: every log line fails to be written (a full
    /// disk under the log, a reader gone). `log()` is empty.
    pub(crate) fn start_unlogged(config: &Path) -> Self {
        let dir = config.parent().unwrap();
        let full = std::fs::OpenOptions::new()
            .write(true)
            .open("/dev/full")
            .unwrap();
        let child = Command::new(env!("CARGO_BIN_EXE_compend"))
            .args(["serve", "--config", config.to_str().unwrap()])
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(full)
            .spawn()
            .unwrap();
        Service {
            child: Some(child),
            socket: dir.join("compend.sock"),
            log: dir.join("no-log"),
        }
    }

    /// `compend serve` with the X display `display` (None: no display).
    fn start_on(config: &Path, display: Option<&str>) -> Self {
        let dir = config.parent().unwrap();
        let log = dir.join(format!("serve-{}.log", Instant::now().elapsed().as_nanos()));
        let log = unique(log);
        let mut cmd = Command::new(env!("CARGO_BIN_EXE_compend"));
        if let Some(d) = display {
            cmd.env("DISPLAY", d).env_remove("WAYLAND_DISPLAY");
        }
        let child = cmd
            .args(["serve", "--config", config.to_str().unwrap()])
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(std::fs::File::create(&log).unwrap())
            .spawn()
            .unwrap();
        Service {
            child: Some(child),
            socket: dir.join("compend.sock"),
            log,
        }
    }

    pub(crate) fn log(&self) -> String {
        std::fs::read_to_string(&self.log).unwrap_or_default()
    }

    /// One request line, one reply.
    pub(crate) fn ask(&self, line: &str) -> Value {
        let mut s = UnixStream::connect(&self.socket)
            .unwrap_or_else(|e| panic!("connect: {e}\nlog:\n{}", self.log()));
        s.set_read_timeout(Some(Duration::from_secs(40))).unwrap();
        s.write_all(line.as_bytes()).unwrap();
        s.write_all(b"\n").unwrap();
        let mut reply = String::new();
        BufReader::new(s).read_line(&mut reply).unwrap();
        serde_json::from_str(reply.trim()).unwrap_or_else(|e| panic!("{e}: {reply:?}"))
    }

    pub(crate) fn status(&self) -> Value {
        let r = self.ask(r#"{"cmd":"status"}"#);
        assert_eq!(r["ok"], true, "{r}");
        r["status"].clone()
    }

    /// Polls the status until `done` holds; panics with the log after `secs`. The process must
    /// stay alive meanwhile.
    pub(crate) fn wait_for(
        &mut self,
        what: &str,
        secs: u64,
        done: impl Fn(&Value) -> bool,
    ) -> Value {
        let start = Instant::now();
        loop {
            if let Some(code) = self.child.as_mut().unwrap().try_wait().unwrap() {
                panic!(
                    "the service exited ({code}) waiting for {what}; log:\n{}",
                    self.log()
                );
            }
            if self.socket.exists()
                && let Ok(mut s) = UnixStream::connect(&self.socket)
            {
                s.set_read_timeout(Some(Duration::from_secs(40))).unwrap();
                s.write_all(b"{\"cmd\":\"status\"}\n").unwrap();
                let mut reply = String::new();
                if BufReader::new(s).read_line(&mut reply).is_ok()
                    && let Ok(v) = serde_json::from_str::<Value>(reply.trim())
                    && done(&v["status"])
                {
                    return v["status"].clone();
                }
            }
            assert!(
                start.elapsed() < Duration::from_secs(secs),
                "no {what} within {secs} s; log:\n{}",
                self.log()
            );
            std::thread::sleep(Duration::from_millis(100));
        }
    }

    /// Waits for the process to exit; its code.
    pub(crate) fn wait_exit(&mut self, secs: u64) -> Option<i32> {
        let start = Instant::now();
        let child = self.child.as_mut().unwrap();
        loop {
            if let Some(status) = child.try_wait().unwrap() {
                self.child = None;
                return status.code();
            }
            assert!(
                start.elapsed() < Duration::from_secs(secs),
                "still running {secs} s after it was told to stop; log:\n{}",
                self.log()
            );
            std::thread::sleep(Duration::from_millis(50));
        }
    }

    fn pid(&self) -> i32 {
        self.child.as_ref().unwrap().id() as i32
    }
}

impl Drop for Service {
    fn drop(&mut self) {
        if let Some(mut c) = self.child.take() {
            let _ = c.kill();
            let _ = c.wait();
            if std::thread::panicking() {
                eprintln!("service log:\n{}", self.log());
            }
        }
    }
}

fn unique(p: PathBuf) -> PathBuf {
    let mut p = p;
    while p.exists() {
        p.set_extension("1.log");
    }
    p
}

pub(crate) fn playing(s: &Value) -> bool {
    s["state"] == "playing" && s["frames"]["shown"].as_u64().unwrap_or(0) > 5
}

pub(crate) fn client(args: &[&str], socket: &Path) -> std::process::Output {
    let mut a = args.to_vec();
    a.extend_from_slice(&["--socket", socket.to_str().unwrap()]);
    compend(&a)
}

pub(crate) fn gpu_or_skip() -> bool {
    crate::common::gpu().is_some()
}

/// `compend::service::serve` inside this process, as mini-redis's tests run its server: given
/// its configuration and a shutdown signal of the test's own, its socket answers; when the
/// signal fires the engine stops, the service itself ends a subscriber's connection (the
/// process does not exit to cut it), `serve` returns Ok and the socket file is gone.
#[test]
fn serve_runs_inside_a_test_process_and_stops_on_the_signal_it_is_given() {
    if !gpu_or_skip() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let path = write_config(dir.path(), "white-plane", 5, "", "");
    let text = std::fs::read_to_string(&path)
        .unwrap()
        .replace("[calibration]\n", "[calibration]\non_start = \"never\"\n");
    std::fs::write(&path, text).unwrap();
    let config = compend::config::Config::load(&path).unwrap();
    let socket = config.socket.path.clone();
    let (stop, stopped) = tokio::sync::oneshot::channel::<()>();
    let serving = std::thread::spawn(move || {
        compend::service::serve(config, None, async move {
            let _ = stopped.await;
            "the test's shutdown signal"
        })
    });
    let deadline = Instant::now() + Duration::from_secs(60);
    let status = loop {
        if let Ok(r) =
            compend::service::socket::request(&socket, &compend::service::protocol::Request::Status)
        {
            break r;
        }
        assert!(Instant::now() < deadline, "the socket never answered");
        assert!(!serving.is_finished(), "serve returned before it answered");
        std::thread::sleep(Duration::from_millis(50));
    };
    assert!(status.ok, "{status:?}");
    let state = serde_json::to_value(&status).unwrap();
    assert_eq!(state["status"]["state"], "idle", "{state}");
    // A subscriber, which would otherwise stay connected for as long as the service runs.
    let mut sub = UnixStream::connect(&socket).unwrap();
    sub.write_all(b"{\"cmd\":\"subscribe\"}\n").unwrap();
    let mut reader = BufReader::new(sub.try_clone().unwrap());
    let mut first = String::new();
    reader.read_line(&mut first).unwrap();
    assert!(first.contains("subscribed"), "{first}");
    // A client between two requests.
    let mut idle = UnixStream::connect(&socket).unwrap();
    idle.write_all(b"{\"cmd\":\"status\"}\n").unwrap();
    let mut idle_reader = BufReader::new(idle.try_clone().unwrap());
    let mut answered = String::new();
    idle_reader.read_line(&mut answered).unwrap();
    assert!(answered.contains("\"ok\":true"), "{answered}");
    stop.send(()).unwrap();
    let result = serving.join().unwrap();
    assert!(result.is_ok(), "{result:?}");
    // The service ended the subscriber's connection: what is left to read ends in EOF, not a
    // timeout.
    sub.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
    let mut rest = String::new();
    std::io::Read::read_to_string(&mut reader, &mut rest).expect("the connection was ended");
    // The client between requests was told why its connection ends.
    idle.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
    let mut told = String::new();
    idle_reader.read_line(&mut told).unwrap();
    assert!(told.contains("the service stopped"), "{told:?}");
    assert!(!socket.exists(), "{} was left behind", socket.display());
}

#[test]
fn the_service_calibrates_plays_and_answers_its_socket() {
    if !gpu_or_skip() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let config = write_config(dir.path(), "textured-plane", 3, "", "");
    // The TCP API too, on a free loopback port, with a token file.
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let token = "5d41402abc4b2a76b9719d911017c592";
    let token_file = dir.path().join("tcp-token");
    std::fs::write(&token_file, format!("{token}\n")).unwrap();
    let text = std::fs::read_to_string(&config).unwrap().replace(
        "[socket]\n",
        &format!(
            "[socket]\ntcp = \"127.0.0.1:{port}\"\ntcp_token_file = \"{}\"\n",
            token_file.display()
        ),
    );
    std::fs::write(&config, text).unwrap();
    let mut svc = Service::start(&config);
    // No model: it calibrates at start, installs the model and plays.
    let s = svc.wait_for("playback after the first calibration", 300, playing);
    assert_eq!(s["calibrations"], 1, "{s}");
    assert_eq!(s["model"]["method"], "linear", "{s}");
    // When and why it is served.
    assert!(
        s["model"]["why"]
            .as_str()
            .unwrap()
            .starts_with("a calibration installed it (verified "),
        "{s}"
    );
    assert!(s["model"]["since_unix_s"].as_f64().unwrap() > 1.7e9, "{s}");
    let v = &s["model"]["verification"];
    assert_eq!(v["passed"], true, "{s}");
    assert!(v["gain_db"].as_f64().unwrap() > 1.0, "{s}");
    let model = dir.path().join("state/model");
    assert!(model.join("model.json").is_file());
    let runs: Vec<_> = std::fs::read_dir(dir.path().join("state/calibration"))
        .unwrap()
        .map(|e| e.unwrap().file_name().into_string().unwrap())
        .collect();
    assert_eq!(runs.len(), 1, "one run folder and no marker left: {runs:?}");
    assert!(runs[0].starts_with("run-"), "{runs:?}");

    // Monitoring scores the compensated view against the intended one.
    let s = svc.wait_for("a monitoring check", 60, |s| {
        s["monitoring"]["checks"].as_u64().unwrap_or(0) >= 2
    });
    let psnr = s["monitoring"]["psnr"].as_f64().unwrap();
    assert!(psnr > 15.0, "monitoring {psnr} dB: {s}");
    assert_eq!(s["monitoring"]["drift"], false, "{s}");

    // The TCP API: requests with the token are answered as on the socket; one without it, or
    // with another, gets an error and the connection is closed.
    // The requests, one after the other's reply; the replies until the service hangs up.
    let tcp = |lines: &[String]| -> Vec<String> {
        let s = std::net::TcpStream::connect(("127.0.0.1", port)).unwrap();
        s.set_read_timeout(Some(Duration::from_secs(40))).unwrap();
        let mut r = BufReader::new(s.try_clone().unwrap());
        let mut w = s;
        let mut replies = Vec::new();
        for l in lines {
            if w.write_all(format!("{l}\n").as_bytes()).is_err() {
                break;
            }
            let mut reply = String::new();
            if r.read_line(&mut reply).unwrap_or(0) == 0 {
                break;
            }
            replies.push(reply.trim().to_string());
        }
        replies
    };
    let replies = tcp(&[
        format!(r#"{{"cmd":"status","token":"{token}"}}"#),
        format!(r#"{{"cmd":"play","source":"nonsense:x","token":"{token}"}}"#),
    ]);
    assert_eq!(replies.len(), 2, "{replies:?}");
    let r: Value = serde_json::from_str(&replies[0]).unwrap();
    assert_eq!(r["status"]["state"], "playing", "{r}");
    let r: Value = serde_json::from_str(&replies[1]).unwrap();
    assert_eq!(r["ok"], false, "{r}");
    assert!(r["error"].as_str().unwrap().contains("nonsense"), "{r}");
    for first in [
        r#"{"cmd":"status"}"#.to_string(),
        r#"{"cmd":"status","token":"5d41402abc4b2a76b9719d911017c59"}"#.to_string(),
        "status".to_string(),
    ] {
        let replies = tcp(&[
            first.clone(),
            format!(r#"{{"cmd":"status","token":"{token}"}}"#),
        ]);
        assert_eq!(replies.len(), 1, "closed after {first}: {replies:?}");
        let r: Value = serde_json::from_str(&replies[0]).unwrap();
        assert_eq!(r["ok"], false, "{r}");
        assert!(r["error"].as_str().unwrap().contains("token"), "{r}");
    }
    assert!(svc.log().contains("control port: refused"), "{}", svc.log());

    // Bad requests get errors; the connection and the service go on.
    let r = svc.ask("hello");
    assert_eq!(r["ok"], false);
    assert!(r["error"].as_str().unwrap().contains("bad request"), "{r}");
    let r = svc.ask(r#"{"cmd":"reboot"}"#);
    assert_eq!(r["ok"], false, "{r}");
    let r = svc.ask(r#"{"cmd":"play","source":"nonsense:x"}"#);
    assert_eq!(r["ok"], false, "{r}");
    let r = svc.ask(r#"{"cmd":"model","path":"/nonexistent/model"}"#);
    assert_eq!(r["ok"], false, "{r}");
    assert!(
        r["error"].as_str().unwrap().contains("/nonexistent/model"),
        "{r}"
    );
    {
        let mut s = UnixStream::connect(&svc.socket).unwrap();
        s.set_read_timeout(Some(Duration::from_secs(20))).unwrap();
        let huge = vec![b'x'; 100_000];
        s.write_all(&huge).unwrap();
        s.write_all(b"\n{\"cmd\":\"status\"}\n").unwrap();
        let mut r = BufReader::new(s);
        let mut line = String::new();
        r.read_line(&mut line).unwrap();
        assert!(line.contains("longer than"), "{line}");
        line.clear();
        r.read_line(&mut line).unwrap();
        assert!(
            line.contains("\"state\""),
            "the same connection answers next: {line}"
        );
    }
    // A model swapped in while playing: the reply comes once it plays, and the playback goes on
    // (a restarted one would count its frames from zero again).
    let shown = svc.status()["frames"]["shown"].as_u64().unwrap();
    let r = svc.ask(&format!(
        r#"{{"cmd":"model","path":"{}"}}"#,
        model.display()
    ));
    assert_eq!(r["ok"], true, "{r}");
    assert!(r["message"].as_str().unwrap().contains("swapped in"), "{r}");
    let s = svc.status();
    assert_eq!(s["state"], "playing", "{s}");
    assert!(
        s["frames"]["shown"].as_u64().unwrap() >= shown,
        "{shown} then {s}"
    );
    assert!(svc.log().contains("swapped in"), "{}", svc.log());
    assert!(
        !r["message"].as_str().unwrap().contains("calibrated on"),
        "its own model: {r}"
    );
    // A model calibrated on another rig (another surface) is swapped in as asked, with a word.
    let other = dir.path().join("other-model");
    std::fs::create_dir(&other).unwrap();
    for name in ["model.safetensors", "model.json"] {
        std::fs::copy(model.join(name), other.join(name)).unwrap();
    }
    let mut meta: serde_json::Value =
        serde_json::from_slice(&std::fs::read(other.join("model.json")).unwrap()).unwrap();
    meta["calibration"]["rig"] = serde_json::json!("virtual:white-plane");
    std::fs::write(other.join("model.json"), meta.to_string()).unwrap();
    let r = svc.ask(&format!(
        r#"{{"cmd":"model","path":"{}"}}"#,
        other.display()
    ));
    assert_eq!(r["ok"], true, "{r}");
    assert!(
        r["message"].as_str().unwrap().contains(
            "warning: it was calibrated on virtual:white-plane, not on this rig \
                       (virtual:textured-plane)"
        ),
        "{r}"
    );
    // The same scene with another seed is another simulated surface: named too.
    assert_eq!(
        meta["calibration"]["seed"], 3,
        "the record keeps the rig's seed"
    );
    meta["calibration"]["rig"] = serde_json::json!("virtual:textured-plane");
    meta["calibration"]["seed"] = serde_json::json!(4);
    std::fs::write(other.join("model.json"), meta.to_string()).unwrap();
    let r = svc.ask(&format!(
        r#"{{"cmd":"model","path":"{}"}}"#,
        other.display()
    ));
    assert_eq!(r["ok"], true, "{r}");
    assert!(
        r["message"]
            .as_str()
            .unwrap()
            .contains("calibrated on virtual:textured-plane with seed 4, not this rig's seed 3"),
        "{r}"
    );
    let r = svc.ask(&format!(
        r#"{{"cmd":"model","path":"{}"}}"#,
        model.display()
    ));
    assert_eq!(r["ok"], true, "{r}");

    // Half a request, then a hang-up: nothing breaks.
    {
        let mut s = UnixStream::connect(&svc.socket).unwrap();
        s.write_all(b"{\"cmd\":\"sta").unwrap();
    }
    // Connections that never finish a request cannot lock the socket out. Past the service's
    // 64 clients, each new one closes the longest idle of them, with a reply that says why;
    // a client that has been asking on its own connection keeps it.
    {
        let kept = UnixStream::connect(&svc.socket).unwrap();
        kept.set_read_timeout(Some(Duration::from_secs(20)))
            .unwrap();
        let mut kept_reader = BufReader::new(kept.try_clone().unwrap());
        let mut ask_kept = || {
            (&kept).write_all(b"{\"cmd\":\"status\"}\n").unwrap();
            let mut line = String::new();
            kept_reader.read_line(&mut line).unwrap();
            assert!(line.contains("\"state\""), "{line}");
        };
        ask_kept();
        let idle: Vec<UnixStream> = (0..70)
            .map(|_| {
                let mut s = UnixStream::connect(&svc.socket).unwrap();
                s.write_all(b"{\"cmd\":").unwrap();
                s
            })
            .collect();
        // A new client is answered at once.
        let start = Instant::now();
        assert_eq!(svc.status()["state"], "playing");
        assert!(
            start.elapsed() < Duration::from_secs(10),
            "{:?}",
            start.elapsed()
        );
        // The first idle ones were closed, saying why.
        let mut first = BufReader::new(idle[0].try_clone().unwrap());
        idle[0]
            .set_read_timeout(Some(Duration::from_secs(20)))
            .unwrap();
        let mut line = String::new();
        first.read_line(&mut line).unwrap();
        assert!(line.contains("closed to make room"), "{line}");
        assert!(line.contains("at most 64 clients"), "{line}");
        ask_kept();
        assert!(
            svc.log().contains("closing the longest idle"),
            "{}",
            svc.log()
        );
    }
    // None of that stopped the playback: frames are still being shown.
    let a = svc.status()["frames"]["shown"].as_u64().unwrap();
    std::thread::sleep(Duration::from_millis(700));
    let s = svc.status();
    assert_eq!(s["state"], "playing");
    assert!(s["frames"]["shown"].as_u64().unwrap() > a, "{a} then {s}");

    // The clients.
    let o = client(&["status", "--json"], &svc.socket);
    assert_code(&o, 0);
    let s: Value = serde_json::from_str(stdout(&o).trim()).unwrap();
    assert_eq!(s["state"], "playing");
    let o = client(&["status"], &svc.socket);
    assert_code(&o, 0);
    assert!(stdout(&o).contains("state: playing"), "{}", stdout(&o));
    assert_code(&client(&["pause"], &svc.socket), 0);
    svc.wait_for("pause", 20, |s| s["state"] == "paused");
    // A recalibration while paused keeps the projector dark before, during and after it;
    // `--wait` reports its outcome.
    let o = client(&["recalibrate", "--wait", "--timeout", "120"], &svc.socket);
    assert_code(&o, 0);
    assert!(
        stdout(&o).contains("last calibration: installed linear"),
        "{}",
        stdout(&o)
    );
    let s = svc.status();
    assert_eq!(s["state"], "paused", "{s}");
    assert_eq!(s["calibrations"], 2, "{s}");
    assert_eq!(s["last_calibration"]["installed"], true, "{s}");
    // A refit asked for (as drift's `on_drift = "refit"` runs it): `[monitoring] refit_ntrain`
    // (8) sampling images and as many closed-loop pairs, in a new run, dark while paused.
    let o = client(
        &["recalibrate", "--refit", "--wait", "--timeout", "120"],
        &svc.socket,
    );
    assert_code(&o, 0);
    assert!(
        stdout(&o).contains("refitting the linear rung from 8"),
        "{}",
        stdout(&o)
    );
    let s = svc.status();
    assert_eq!(s["state"], "paused", "{s}");
    assert_eq!(s["calibrations"], 3, "{s}");
    let refitted: Value =
        serde_json::from_slice(&std::fs::read(dir.path().join("state/model/model.json")).unwrap())
            .unwrap();
    assert_eq!(refitted["training"]["ntrain"], 16, "{refitted}");
    assert_eq!(refitted["calibration"]["loop_pairs"], 8, "{refitted}");
    let why = s["model"]["why"].as_str().unwrap();
    assert!(why.starts_with("a refit installed it"), "{s}");
    let o = client(&["status"], &svc.socket);
    assert!(stdout(&o).contains(&format!(": {why}\n")), "{}", stdout(&o));
    // A model swapped in while paused keeps the projector dark: no frame until `play`.
    let shown = s["frames"]["shown"].clone();
    let r = svc.ask(&format!(
        r#"{{"cmd":"model","path":"{}"}}"#,
        model.display()
    ));
    assert_eq!(r["ok"], true, "{r}");
    assert!(r["message"].as_str().unwrap().starts_with("paused"), "{r}");
    std::thread::sleep(Duration::from_millis(700));
    let s = svc.status();
    assert_eq!(s["state"], "paused", "{s}");
    assert_eq!(s["frames"]["shown"], shown, "{s}");
    assert_code(&client(&["play"], &svc.socket), 0);
    svc.wait_for("playback again", 30, playing);
    let o = client(
        &["ctl", r#"{"cmd":"play","source":"pattern:nope"}"#],
        &svc.socket,
    );
    assert_code(&o, 1);
    assert!(stdout(&o).contains("\"ok\":false"), "{}", stdout(&o));
    // Nor does a source that parses but cannot be played: a damaged image, an empty folder.
    // Each is refused, naming it, and the picture that is on stays on: the playback is not
    // even restarted (its frame count, reset when a playback starts, goes on growing).
    let source = svc.status()["source"].clone();
    std::thread::sleep(Duration::from_millis(1500));
    let damaged = dir.path().join("damaged.png");
    std::fs::write(&damaged, &b"\x89PNG\r\n\x1a\n"[..]).unwrap();
    let empty = dir.path().join("empty");
    std::fs::create_dir(&empty).unwrap();
    // A FIFO named like an image, and a device, are refused without waiting for a writer or
    // reading without end.
    let fifo = dir.path().join("fifo.png");
    let made = std::process::Command::new("mkfifo")
        .arg(&fifo)
        .status()
        .unwrap();
    assert!(made.success());
    let zero = PathBuf::from("/dev/zero");
    for (bad, says) in [
        (&damaged, "not a readable image"),
        (&empty, "no PNG or JPEG images"),
        (&fifo, "a FIFO (named pipe), not an image"),
        // A device, and outside the media folders besides: refused for that first.
        (&zero, "not in [playback] media"),
    ] {
        let a = svc.status()["frames"]["shown"].as_u64().unwrap();
        let spelt = format!("image:{}", bad.display());
        let spelt = if bad == &empty {
            bad.display().to_string()
        } else {
            spelt
        };
        let o = client(&["play", "--source", &spelt], &svc.socket);
        assert_code(&o, 1);
        let said = format!("{}{}", stdout(&o), stderr(&o));
        assert!(said.contains(says), "{said}");
        assert!(said.contains(bad.to_str().unwrap()), "{said}");
        std::thread::sleep(Duration::from_millis(700));
        let s = svc.status();
        assert_eq!(s["state"], "playing", "{s}");
        assert_eq!(s["source"], source, "{s}");
        assert!(s["frames"]["shown"].as_u64().unwrap() > a, "{a} then {s}");
    }
    // Paused, the same: the request is refused and the service stays paused.
    assert_code(&client(&["pause"], &svc.socket), 0);
    svc.wait_for("pause", 20, |s| s["state"] == "paused");
    let o = client(
        &["play", "--source", damaged.to_str().unwrap()],
        &svc.socket,
    );
    assert_code(&o, 1);
    std::thread::sleep(Duration::from_millis(500));
    assert_eq!(svc.status()["state"], "paused");
    assert_code(&client(&["play"], &svc.socket), 0);
    svc.wait_for("playback again", 30, playing);
    assert_eq!(svc.status()["source"], source);
    // A raw FIFO no one writes into plays (its first frame waits on the source's own thread):
    // the service answers and stops as ever.
    let raw = format!("raw:{}?size=8x8", fifo.display());
    assert_code(&client(&["play", "--source", &raw], &svc.socket), 0);
    std::thread::sleep(Duration::from_millis(500));
    assert_eq!(svc.status()["source"], raw.as_str());

    assert_code(&client(&["stop"], &svc.socket), 0);
    assert_eq!(svc.wait_exit(20), Some(0), "log:\n{}", svc.log());
    assert!(!svc.socket.exists(), "the socket is removed at exit");
    // No service: a failed operation, not a typo.
    let o = client(&["status"], &svc.socket);
    assert_code(&o, 1);
    assert!(
        stderr(&o).contains("is `compend serve` running"),
        "{}",
        stderr(&o)
    );
}

#[test]
fn a_killed_recalibration_keeps_the_model_and_resumes_after_a_restart() {
    if !gpu_or_skip() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    // ntrain 12 captures in a blink: the kill must land in the middle of the captures, so this
    // run captures more.
    let config = write_config(dir.path(), "curved", 5, "", "enabled = false");
    // And closed-loop pairs: taken after the training, with the verification.
    let text = std::fs::read_to_string(&config)
        .unwrap()
        .replace("ntrain = 12", "ntrain = 40\nloop_images = 4");
    std::fs::write(&config, text).unwrap();
    // The first model from `compend calibrate --config`, which installs where the service
    // serves from.
    let o = compend(&["calibrate", "--config", config.to_str().unwrap(), "--json"]);
    assert_code(&o, 0);
    let model = dir.path().join("state/model");
    let weights = std::fs::read(model.join("model.safetensors")).unwrap();
    let meta = std::fs::read(model.join("model.json")).unwrap();

    let mut svc = Service::start(&config);
    svc.wait_for("playback of the installed model", 120, playing);
    let r = svc.ask(r#"{"cmd":"recalibrate"}"#);
    assert_eq!(r["ok"], true, "{r}");
    let s = svc.wait_for("captures of the recalibration", 120, |s| {
        s["calibration"]["phase"] == "captures" && s["calibration"]["done"].as_u64() >= Some(8)
    });
    // While calibrating, status answers and other requests are refused politely.
    assert_eq!(s["state"], "calibrating", "{s}");
    let r = svc.ask(r#"{"cmd":"pause"}"#);
    assert_eq!(r["ok"], false, "{r}");
    assert!(r["error"].as_str().unwrap().contains("busy"), "{r}");
    // kill -9.
    let pid = svc.pid();
    unsafe { libc::kill(pid, libc::SIGKILL) };
    assert_eq!(svc.wait_exit(10), None, "killed by a signal");
    assert_eq!(
        std::fs::read(model.join("model.safetensors")).unwrap(),
        weights
    );
    assert_eq!(std::fs::read(model.join("model.json")).unwrap(), meta);
    let marker = dir.path().join("state/calibration/calibrating.json");
    assert!(
        marker.is_file(),
        "the marker says a calibration was interrupted"
    );

    // The restarted service (the socket file is stale: replaced) resumes the run: the captures
    // it lacks, then the training beside playback of the installed model. Kill -9 again while
    // it trains.
    let mut svc = Service::start(&config);
    let s = svc.wait_for("training beside playback", 120, |s| {
        s["state"] == "playing" && !s["calibration"].is_null()
    });
    assert_eq!(s["model"]["method"], "linear", "the old model plays: {s}");
    unsafe { libc::kill(svc.pid(), libc::SIGKILL) };
    assert_eq!(svc.wait_exit(10), None, "killed by a signal");
    assert_eq!(
        std::fs::read(model.join("model.safetensors")).unwrap(),
        weights
    );
    assert_eq!(std::fs::read(model.join("model.json")).unwrap(), meta);
    assert!(marker.is_file());

    // Restarted once more, it resumes again (every capture on disk) and installs.
    let mut svc = Service::start(&config);
    let s = svc.wait_for("playback after the resumed calibration", 300, |s| {
        playing(s) && s["calibrations"] == 1
    });
    assert!(!marker.exists());
    let meta: Value =
        serde_json::from_slice(&std::fs::read(model.join("model.json")).unwrap()).unwrap();
    let resumed = meta["calibration"]["resumed"].as_u64().unwrap();
    assert!(
        resumed >= 40,
        "{resumed} captures resumed: {}",
        meta["calibration"]
    );
    assert_eq!(s["model"]["verification"]["passed"], true, "{s}");
    assert_eq!(
        meta["calibration"]["loop_pairs"], 4,
        "{}",
        meta["calibration"]
    );
    assert_eq!(meta["training"]["ntrain"], 44, "{}", meta["training"]);
    assert_ne!(
        std::fs::read(model.join("model.safetensors")).unwrap(),
        weights
    );

    // SIGTERM: exit 0, promptly.
    unsafe { libc::kill(svc.pid(), libc::SIGTERM) };
    assert_eq!(svc.wait_exit(20), Some(0), "log:\n{}", svc.log());
}

/// A set of projectors served (`[rig] scene = "tiled"`, two `[[projector]]` sections): with no
/// model the service calibrates the set as a whole, installs the set's model and plays it
/// through the joint pass on both projectors; the status gives the whole set's verification
/// (seam figure included) and each projector's; monitoring scores the camera's view of the
/// whole set; one projector's model is refused and the set plays on; pause, play and a
/// restart that serves the installed set; stop.
#[test]
fn the_service_calibrates_and_plays_a_set_of_projectors() {
    if !gpu_or_skip() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let config = write_config(dir.path(), "tiled", 9, "", "");
    // The virtual rig brings its own outputs: the sections count them, and send each
    // projector's frames to a file of its own too.
    let sections = format!(
        "[[projector]]\nto = \"file:{}\"\n[[projector]]\nto = \"file:{}\"\n\n[paths]\n",
        dir.path().join("left.mkv").display(),
        dir.path().join("right.mkv").display()
    );
    let text = std::fs::read_to_string(&config)
        .unwrap()
        .replace("[paths]\n", &sections);
    std::fs::write(&config, text).unwrap();
    let mut svc = Service::start(&config);
    let s = svc.wait_for("playback of the set after its calibration", 600, playing);
    assert_eq!(s["calibrations"], 1, "{s}");
    assert_eq!(s["model"]["method"], "linear (a set of 2, joint)", "{s}");
    let set = &s["model"]["set"];
    assert_eq!(set["passed"], true, "{s}");
    assert!(set["gain_db"].as_f64().unwrap() >= 0.0, "{s}");
    assert!(
        set["seam"]["band_mse"].as_f64().is_some(),
        "a tiled set overlaps: {s}"
    );
    assert!(
        s["model"]["why"]
            .as_str()
            .unwrap()
            .starts_with("a calibration installed it (verified "),
        "{s}"
    );
    let p = s["projectors"].as_array().unwrap();
    assert_eq!(p.len(), 2, "{s}");
    for (k, p) in p.iter().enumerate() {
        assert_eq!(p["output"], format!("virtual projector {}", k + 1), "{s}");
        assert_eq!(p["size"], "200x150", "{s}");
        assert_eq!(p["verification"]["passed"], true, "{s}");
    }
    let model = dir.path().join("state/model");
    assert!(model.join("set.json").is_file());
    assert!(model.join("projector-2/model.json").is_file());
    let text = stdout(&client(&["status"], &svc.socket));
    assert!(
        text.contains("the whole set verified: ")
            && text.contains("projector 2: virtual projector 2 (200x150), verified alone "),
        "{text}"
    );

    // Monitoring scores the whole set's view against the desired one.
    let s = svc.wait_for("a monitoring check of the set", 60, |s| {
        s["monitoring"]["checks"].as_u64().unwrap_or(0) >= 2
    });
    let psnr = s["monitoring"]["psnr"].as_f64().unwrap();
    assert!(psnr > 15.0, "monitoring {psnr} dB: {s}");
    assert_eq!(s["monitoring"]["drift"], false, "{s}");
    // The tiled pictures overlap: every check gives the seam figure too, against the first.
    let seam = s["monitoring"]["seam_ratio"].as_f64().unwrap();
    let first = s["monitoring"]["seam_baseline"].as_f64().unwrap();
    assert!(seam > 0.0 && first > 0.0, "seam ratio {seam}: {s}");
    assert!(!svc.log().contains("a seam shows"), "{}", svc.log());
    // And each projector's part of the area, scored on its own.
    let parts: Vec<f64> = s["monitoring"]["projectors_psnr"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| p.as_f64().unwrap())
        .collect();
    assert_eq!(parts.len(), 2, "{s}");
    assert!(parts.iter().all(|&p| p > 15.0), "{s}");
    let text = stdout(&client(&["status"], &svc.socket));
    assert!(
        text.contains("monitoring: seam ratio ")
            && text.contains("monitoring: each projector's part of the area: "),
        "{text}"
    );

    // One projector's model is not a set's: refused, the set plays on.
    let one = dir.path().join("one");
    std::fs::create_dir(&one).unwrap();
    for f in ["model.json", "model.safetensors"] {
        std::fs::copy(model.join("projector-1").join(f), one.join(f)).unwrap();
    }
    let r = svc.ask(&format!(r#"{{"cmd":"model","path":"{}"}}"#, one.display()));
    assert_eq!(r["ok"], false, "{r}");
    assert!(
        r["error"]
            .as_str()
            .unwrap()
            .contains("one projector's model"),
        "{r}"
    );
    svc.wait_for("the set playing on", 30, playing);
    assert_eq!(
        svc.status()["model"]["method"],
        "linear (a set of 2, joint)"
    );

    // Pause (black on both projectors) and play again.
    let r = svc.ask(r#"{"cmd":"pause"}"#);
    assert_eq!(r["ok"], true, "{r}");
    svc.wait_for("paused", 30, |s| s["state"] == "paused");
    let r = svc.ask(r#"{"cmd":"play"}"#);
    assert_eq!(r["ok"], true, "{r}");
    svc.wait_for("playing again", 30, playing);
    let r = svc.ask(r#"{"cmd":"stop"}"#);
    assert_eq!(r["ok"], true, "{r}");
    assert_eq!(svc.wait_exit(30), Some(0), "log:\n{}", svc.log());
    // Each playback wrote each projector's file, complete once it ended.
    for side in ["left", "right"] {
        let first = dir.path().join(format!("{side}-0001.mkv"));
        let len = std::fs::metadata(&first).map_or(0, |m| m.len());
        assert!(
            len > 1000,
            "{}: {len} bytes; log:\n{}",
            first.display(),
            svc.log()
        );
    }

    // Restarted, it serves the installed set at once.
    let mut svc = Service::start(&config);
    let s = svc.wait_for("playback of the installed set", 120, playing);
    assert_eq!(s["calibrations"], 0, "{s}");
    assert_eq!(s["model"]["method"], "linear (a set of 2, joint)", "{s}");
    assert!(
        s["model"]["why"]
            .as_str()
            .unwrap()
            .contains("when the service started"),
        "{s}"
    );
    unsafe { libc::kill(svc.pid(), libc::SIGTERM) };
    assert_eq!(svc.wait_exit(20), Some(0), "log:\n{}", svc.log());

    // Sections that do not match the scene's projectors are named before anything opens.
    let second = format!(
        "[[projector]]\nto = \"file:{}\"\n",
        dir.path().join("right.mkv").display()
    );
    let text = std::fs::read_to_string(&config).unwrap();
    assert!(text.contains(&second));
    let text = text.replace(&second, "");
    std::fs::write(&config, text).unwrap();
    let o = compend(&["config", "check", config.to_str().unwrap()]);
    assert_code(&o, 2);
    assert!(
        stderr(&o).contains("[[projector]]: 1 section(s), and scene \"tiled\" has 2"),
        "{}",
        stderr(&o)
    );
}

/// The built-in drift scene moves its projector by 1.5 of 800 pixels, which at the tests'
/// 200-pixel projector is a third of a pixel: monitoring sees 0.5 dB of it. A bump, here, is 24
/// of 800 pixels (6 at this size), as a scene file in `dir`.
fn bumped_scene(dir: &Path) -> PathBuf {
    let o = compend(&["sim", "show", "drift"]);
    assert_code(&o, 0);
    let mut scene: Value = serde_json::from_str(&stdout(&o)).unwrap();
    scene["drift"]["shift_px"] = serde_json::json!([24.0, -16.0]);
    let scene_file = dir.join("bumped.json");
    std::fs::write(&scene_file, scene.to_string()).unwrap();
    scene_file
}

#[test]
fn drift_is_detected_and_refitted_from_a_handful_of_captures() {
    if !gpu_or_skip() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let scene_file = bumped_scene(dir.path());
    let config = write_config(
        dir.path(),
        scene_file.to_str().unwrap(),
        2,
        "drift_after_s = 2.0",
        "drift_threshold_db = 2.0\non_drift = \"refit\"\nrefit_ntrain = 6",
    );
    let mut svc = Service::start(&config);
    let s = svc.wait_for("a refit after drift", 420, |s| {
        s["calibrations"].as_u64() >= Some(2) && playing(s)
    });
    assert!(s["monitoring"]["drifts"].as_u64() >= Some(1), "{s}");
    let log = svc.log();
    assert!(
        log.contains("drift: refitting the linear rung from 6 sampling images"),
        "{log}"
    );
    // The refit projected 6 sampling images, the 3 verified test images and 6 closed-loop
    // pairs (18 captures with black, white and gray, against 31 for the first calibration) and
    // fitted on the 6 sampling and 6 closed-loop pairs.
    let meta: Value =
        serde_json::from_slice(&std::fs::read(dir.path().join("state/model/model.json")).unwrap())
            .unwrap();
    assert_eq!(meta["training"]["ntrain"], 12, "{meta}");
    assert_eq!(meta["calibration"]["captured"], 18, "{meta}");
    assert_eq!(meta["calibration"]["loop_pairs"], 6, "{meta}");
    assert_eq!(
        meta["calibration"]["verification"]["passed"], true,
        "{meta}"
    );
    // The old model played while the new one trained.
    assert!(
        log.contains("training linear beside playback of the current model"),
        "{log}"
    );
    // Two run folders: the recalibration captured afresh.
    let runs = std::fs::read_dir(dir.path().join("state/calibration"))
        .unwrap()
        .filter(|e| {
            e.as_ref()
                .unwrap()
                .file_name()
                .to_string_lossy()
                .starts_with("run-")
        })
        .count();
    assert_eq!(runs, 2);
    // The new model scores near its own baseline after the move.
    let s = svc.wait_for("monitoring of the new model", 60, |s| {
        s["monitoring"]["checks"].as_u64() >= Some(2)
    });
    assert_eq!(s["monitoring"]["drift"], false, "{s}");
    unsafe { libc::kill(svc.pid(), libc::SIGINT) };
    assert_eq!(svc.wait_exit(20), Some(0));
}

#[test]
fn bad_configurations_and_sockets_exit_2_and_touch_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let bad = dir.path().join("bad.toml");
    std::fs::write(
        &bad,
        "[rig]\nkind = \"virtual\"\nscnee = \"curved\"\n[calibration]\nntrain = -3\n\
         [monitoring]\nperiod_s = 0\n",
    )
    .unwrap();
    for args in [
        vec!["serve", "--config", bad.to_str().unwrap()],
        vec!["config", "check", bad.to_str().unwrap()],
        vec!["calibrate", "--config", bad.to_str().unwrap()],
    ] {
        let o = compend(&args);
        assert_code(&o, 2);
        let e = stderr(&o);
        for want in [
            "bad.toml:3: unknown key `scnee` at the [rig]; did you mean `scene`?",
            "bad.toml:5: [calibration] ntrain",
            "bad.toml:7: [monitoring] period_s",
            "3 errors",
        ] {
            assert!(e.contains(want), "{args:?}: missing {want:?} in:\n{e}");
        }
    }
    let o = compend(&[
        "serve",
        "--config",
        dir.path().join("none.toml").to_str().unwrap(),
    ]);
    assert_code(&o, 2);
    assert!(stderr(&o).contains("none.toml"), "{}", stderr(&o));

    // The model path holds something that is not a model: refused at start, the file kept;
    // `config check` says so too, as it does of a scene that does not exist and of a data path
    // that is a file.
    let config = write_config(dir.path(), "curved", 0, "", "");
    // A good file on the virtual rig: OK, and a word that the rig is simulated.
    let o = compend(&["config", "check", config.to_str().unwrap()]);
    assert_code(&o, 0);
    assert!(
        stdout(&o).contains("note: [rig] kind = \"virtual\" is a simulated projector"),
        "{}",
        stdout(&o)
    );
    let model = dir.path().join("state/model");
    std::fs::create_dir_all(&model).unwrap();
    std::fs::write(model.join("notes.txt"), "mine").unwrap();
    for args in [
        ["serve", "--config", config.to_str().unwrap()],
        ["config", "check", config.to_str().unwrap()],
    ] {
        let o = compend(&args);
        assert_code(&o, 2);
        assert!(
            stderr(&o).contains("not a model directory"),
            "{args:?}: {}",
            stderr(&o)
        );
    }
    let text = std::fs::read_to_string(&config).unwrap();
    let elsewhere = dir.path().join("elsewhere.toml");
    let file = dir.path().join("a-file");
    std::fs::write(&file, "mine").unwrap();
    for (from, to, says) in [
        (
            "scene = \"curved\"",
            "scene = \"no-such-scene\"",
            "no-such-scene",
        ),
        (
            "[paths]\n",
            &format!("[paths]\ndata = \"{}\"\n", file.display()),
            "[paths] data",
        ),
        // The virtual rig's set has its own outputs.
        (
            "[paths]\n",
            "[[projector]]\nmonitor = \"DP-1\"\n\n[paths]\n",
            "[[projector]] 1 monitor: the virtual rig has its own outputs",
        ),
    ] {
        assert!(text.contains(from), "{text}");
        std::fs::write(&elsewhere, text.replace(from, to)).unwrap();
        let o = compend(&["config", "check", elsewhere.to_str().unwrap()]);
        assert_code(&o, 2);
        assert!(stderr(&o).contains(says), "{}", stderr(&o));
    }
    assert_eq!(std::fs::read_to_string(&file).unwrap(), "mine");
    assert_eq!(
        std::fs::read_to_string(model.join("notes.txt")).unwrap(),
        "mine"
    );
    std::fs::remove_dir_all(&model).unwrap();

    // The TCP API: a non-loopback address and a missing token file are configuration errors;
    // a short token stops the service at start.
    let tcp_config = |extra: &str| {
        let text = std::fs::read_to_string(&config)
            .unwrap()
            .replace("[socket]\n", &format!("[socket]\n{extra}\n"));
        let path = dir.path().join("tcp.toml");
        std::fs::write(&path, text).unwrap();
        path
    };
    let c = tcp_config("tcp = \"0.0.0.0:7420\"");
    let o = compend(&["config", "check", c.to_str().unwrap()]);
    assert_code(&o, 2);
    for want in [
        "[socket] tcp",
        "not a loopback address",
        "needs tcp_token_file",
    ] {
        assert!(stderr(&o).contains(want), "{want}: {}", stderr(&o));
    }
    let short = dir.path().join("short-token");
    std::fs::write(&short, "abc\n").unwrap();
    let c = tcp_config(&format!(
        "tcp = \"127.0.0.1:7420\"\ntcp_token_file = \"{}\"",
        short.display()
    ));
    let o = compend(&["serve", "--config", c.to_str().unwrap()]);
    assert_code(&o, 2);
    assert!(
        stderr(&o).contains("short-token") && stderr(&o).contains("at least 16"),
        "{}",
        stderr(&o)
    );

    // The socket path holds a file: refused, the file kept.
    let socket = dir.path().join("compend.sock");
    std::fs::write(&socket, "not a socket").unwrap();
    let o = compend(&["serve", "--config", config.to_str().unwrap()]);
    assert_code(&o, 2);
    assert!(stderr(&o).contains("is not a socket"), "{}", stderr(&o));
    assert_eq!(std::fs::read_to_string(&socket).unwrap(), "not a socket");
    std::fs::remove_file(&socket).unwrap();

    // A second service on the same state directory, even on another socket, is refused: the
    // first holds the directory's lock.
    let lock_path = dir.path().join("state/compend.lock");
    // Held by a live process (this one) that says it is a service.
    let me = std::process::id();
    std::fs::write(&lock_path, format!("{me} serve\n")).unwrap();
    let lock = std::fs::File::open(&lock_path).unwrap();
    lock.try_lock().unwrap();
    let o = compend(&["serve", "--config", config.to_str().unwrap()]);
    assert_code(&o, 2);
    assert!(
        stderr(&o).contains(&format!(
            "`compend serve` (pid {me}) holds this state directory; one service runs per state"
        )),
        "{}",
        stderr(&o)
    );
    assert!(!socket.exists());
    // Nor does `calibrate` on the service's configuration capture from its rig and install
    // into its model path while it runs; the service calibrates on request.
    let o = compend(&["calibrate", "--config", config.to_str().unwrap()]);
    assert_code(&o, 2);
    assert!(
        stderr(&o).contains(&format!("(pid {me}) holds this state directory; the running service calibrates on request (`compend recalibrate`)")),
        "{}",
        stderr(&o)
    );
    assert!(!dir.path().join("state/model").exists());
    // Nor without the configuration, into the service's model path.
    let o = compend(&[
        "calibrate",
        "--rig",
        "virtual:curved",
        "--out",
        dir.path().join("state/model").to_str().unwrap(),
        "--data",
        dir.path().join("elsewhere").to_str().unwrap(),
    ]);
    assert_code(&o, 2);
    assert!(
        stderr(&o).contains(&format!("(pid {me}) holds this state directory")),
        "{}",
        stderr(&o)
    );
    assert!(!dir.path().join("state/model").exists());
    assert_eq!(
        std::fs::read_to_string(&lock_path).unwrap(),
        format!("{me} serve\n")
    );
    // A calibration holding it keeps a service from starting.
    std::fs::write(&lock_path, format!("{me} calibrate\n")).unwrap();
    let o = compend(&["serve", "--config", config.to_str().unwrap()]);
    assert_code(&o, 2);
    assert!(
        stderr(&o).contains(&format!(
            "`compend calibrate` (pid {me}) holds this state directory; wait"
        )),
        "{}",
        stderr(&o)
    );
    // A pid that no longer runs (left by a holder that could not write the file) is not
    // named as the holder.
    std::fs::write(&lock_path, "999999999 serve\n").unwrap();
    let o = compend(&["serve", "--config", config.to_str().unwrap()]);
    assert_code(&o, 2);
    assert!(
        stderr(&o).contains("another compend process holds this state directory"),
        "{}",
        stderr(&o)
    );
    drop(lock);

    // A second service on a live socket is refused; the first goes on.
    let listener = std::os::unix::net::UnixListener::bind(&socket).unwrap();
    let o = compend(&["serve", "--config", config.to_str().unwrap()]);
    assert_code(&o, 2);
    assert!(
        stderr(&o).contains("another compend service"),
        "{}",
        stderr(&o)
    );
    drop(listener);
    assert!(socket.exists());

    // The shipped example parses and documents every key the parser knows.
    let shipped = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/compend.toml");
    let o = compend(&["config", "check", shipped.to_str().unwrap(), "--json"]);
    assert_code(&o, 0);
    let text = std::fs::read_to_string(&shipped).unwrap();
    for key in compend::config::known_keys() {
        let (section, name) = key.split_once('.').unwrap();
        let at = text
            .find(&format!("[{section}]"))
            .unwrap_or_else(|| panic!("config/compend.toml has no [{section}]"));
        let rest = &text[at..];
        let end = rest[1..].find("\n[").map_or(rest.len(), |i| i + 1);
        let body = &rest[..end];
        assert!(
            body.lines().any(|l| {
                let l = l.trim_start_matches(['#', ' ']);
                l.starts_with(&format!("{name} ="))
            }),
            "config/compend.toml does not document {key}"
        );
    }
}

#[test]
#[cfg(feature = "benches")]
fn bench_serve_measures_the_targets_on_a_tiny_rig() {
    let dir = tempfile::tempdir().unwrap();
    // A folder that holds something is refused before any work.
    std::fs::write(dir.path().join("notes.txt"), "mine").unwrap();
    let o = compend(&["bench-serve", "--out", dir.path().to_str().unwrap()]);
    assert_code(&o, 2);
    assert!(stderr(&o).contains("not empty"), "{}", stderr(&o));
    assert_eq!(
        std::fs::read_to_string(dir.path().join("notes.txt")).unwrap(),
        "mine"
    );
    if !gpu_or_skip() {
        return;
    }
    let out = dir.path().join("bench");
    let o = compend(&[
        "bench-serve",
        "--out",
        out.to_str().unwrap(),
        "--camera",
        "160x120",
        "--projector",
        "200x150",
        "--ntrain",
        "12",
        "--malformed",
        "400",
        "--swaps",
        "1",
        "--window",
        "0.5",
        "--period",
        "0.5",
        "--browsers",
        "2",
        "--console-rounds",
        "1",
    ]);
    assert_code(&o, 0);
    let r: Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("bench-serve.json")).unwrap())
            .unwrap();
    assert_eq!(r["flood"]["error_replies"], 400, "{r}");
    assert_eq!(r["flood"]["still_playing"], true, "{r}");
    assert!(r["status"]["training"]["n"].as_u64().unwrap() > 0, "{r}");
    assert!(
        r["swaps"][0]["reply"]
            .as_str()
            .unwrap()
            .contains("swapped in"),
        "{r}"
    );
    assert!(r["drift"]["detected_after_s"].is_number(), "{r}");
    // The console's load really loaded it: images fetched, events read, OSC answered.
    let c = &r["console"][0];
    assert!(c["camera_images"].as_u64().unwrap() > 0, "{r}");
    assert!(c["osc_replies"].as_u64().unwrap() > 0, "{r}");
    assert!(c["with_load"]["shown"].as_u64().unwrap() > 0, "{r}");
    assert!(
        r["status"]["http_playing"]["n"].as_u64().unwrap() > 0,
        "{r}"
    );
    for stop in r["stops"].as_array().unwrap() {
        assert_eq!(stop["exit_code"], 0, "{r}");
    }
    assert!(out.join("bench-serve.md").is_file());
}

#[test]
fn progressive_calibration_climbs_only_when_the_rig_says_so() {
    if !gpu_or_skip() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let config = write_config(dir.path(), "curved-ambient", 6, "", "enabled = false");
    let base = std::fs::read_to_string(&config).unwrap();
    let climbing = |rung: &str, gain: &str| {
        base.replace(
            "network = \"64\"",
            &format!(
                "network = \"64\"\nclimb = \"{rung}\"\nclimb_iters = 8\n\
                 climb_gain_db = {gain}"
            ),
        )
    };
    // A margin no rung can show: the climb trains on every pair (its correction on the 12
    // closed-loop pairs the calibration took with `linear`), the playback stops while the rig
    // projects both models, and nothing changes. Its live pass is timed first on the playback
    // GPU, and fits a refresh every 1000 s.
    std::fs::write(
        &config,
        climbing("compennet++-res", "100.0\nrefresh_hz = 0.001"),
    )
    .unwrap();
    let mut svc = Service::start(&config);
    svc.wait_for("playback of the calibrated model", 300, playing);
    let model = dir.path().join("state/model");
    let weights = std::fs::read(model.join("model.safetensors")).unwrap();
    let start = Instant::now();
    while !svc.log().contains("progressive calibration: kept linear") {
        assert!(
            start.elapsed() < Duration::from_secs(300),
            "log:\n{}",
            svc.log()
        );
        std::thread::sleep(Duration::from_millis(200));
    }
    assert_eq!(
        std::fs::read(model.join("model.safetensors")).unwrap(),
        weights
    );
    let s = svc.status();
    assert_eq!(s["model"]["method"], "linear");
    assert_eq!(s["last_climb"]["installed"], false, "{s}");
    assert!(
        s["last_climb"]["message"]
            .as_str()
            .unwrap()
            .starts_with("kept linear: on the rig compennet++-res scored"),
        "{s}"
    );
    let climb = &s["last_climb"]["message"].as_str().unwrap();
    assert!(
        climb.contains("+100.00 needed") && climb.contains("on the held-out test pairs"),
        "{s}"
    );
    assert!(
        svc.log()
            .contains("progressive calibration: compennet++-res's live pass takes"),
        "log:\n{}",
        svc.log()
    );

    // A new configuration, reloaded with SIGHUP (the `n`th reload), and a recalibration.
    let recalibrate_with = |svc: &mut Service, text: String, n: usize| {
        std::fs::write(&config, text).unwrap();
        unsafe { libc::kill(svc.pid(), libc::SIGHUP) };
        let start = Instant::now();
        while svc.log().matches("reload: configuration applied").count() < n {
            assert!(
                start.elapsed() < Duration::from_secs(20),
                "log:\n{}",
                svc.log()
            );
            std::thread::sleep(Duration::from_millis(50));
        }
        assert_eq!(svc.ask(r#"{"cmd":"recalibrate"}"#)["ok"], true);
    };

    // A configuration whose next start would fail (a scene that does not exist) is not
    // applied: the running one stays.
    std::fs::write(
        &config,
        climbing("compennet++-res", "-100.0").replace("curved-ambient", "no-such-scene"),
    )
    .unwrap();
    unsafe { libc::kill(svc.pid(), libc::SIGHUP) };
    let start = Instant::now();
    while !svc.log().contains("the configuration was not reloaded") {
        assert!(
            start.elapsed() < Duration::from_secs(20),
            "log:\n{}",
            svc.log()
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    assert!(svc.log().contains("no-such-scene"), "log:\n{}", svc.log());
    assert!(!svc.log().contains("reload: configuration applied"));

    // The residual rung with any gain: trained on every pair, confirmed by the rig and
    // installed, with its figures on the test pairs recorded beside the rig's.
    recalibrate_with(
        &mut svc,
        climbing("compennet++-res", "-100.0\nrefresh_hz = 0.001"),
        1,
    );
    let s = svc.wait_for("the residual rung playing", 300, |s| {
        playing(s) && s["model"]["method"] == "compennet++-res"
    });
    assert_eq!(s["calibrations"], 2, "{s}");
    assert_eq!(s["last_climb"]["installed"], true, "{s}");
    assert_eq!(s["model"]["climb"]["replaced"], "linear", "{s}");
    assert_eq!(s["model"]["climb"]["closed_loop"]["passed"], true, "{s}");
    assert!(s["model"]["climb"].get("loop_held_out").is_none(), "{s}");
    assert!(s["model"]["climb"]["psnr"].is_number(), "{s}");
    let meta: Value =
        serde_json::from_slice(&std::fs::read(model.join("model.json")).unwrap()).unwrap();
    assert_eq!(meta["method"], "compennet++-res", "{meta}");
    assert_eq!(meta["training"]["iterations"], 8, "{meta}");
    assert!(
        meta["training"]["correction"]
            .as_str()
            .unwrap()
            .starts_with("12 closed-loop pairs"),
        "{meta}"
    );

    // Any gain will do, and a recalibration: the playback stops while the rig projects the
    // climbed rung and the installed one, and it is installed and played, with its evidence.
    recalibrate_with(&mut svc, climbing("compennet++-cpu", "-100.0"), 2);
    let s = svc.wait_for("the climbed model playing", 300, |s| {
        playing(s) && s["model"]["method"] == "compennet++-cpu"
    });
    assert_eq!(s["calibrations"], 3, "{s}");
    assert_eq!(s["last_climb"]["method"], "compennet++-cpu", "{s}");
    assert_eq!(s["last_climb"]["installed"], true, "{s}");
    let climb = &s["model"]["climb"];
    assert_eq!(climb["replaced"], "linear", "{s}");
    assert!(
        climb["psnr"].is_number() && climb["replaced_psnr"].is_number(),
        "{s}"
    );
    let rig = &climb["closed_loop"];
    assert_eq!(rig["images"], 3, "{s}");
    assert!(
        rig["psnr"].is_number() && rig["replaced_psnr"].is_number() && rig["passed"] == true,
        "{s}"
    );
    assert!(
        svc.log().contains("in closed loop on 3 images"),
        "log:\n{}",
        svc.log()
    );
    let meta: Value =
        serde_json::from_slice(&std::fs::read(model.join("model.json")).unwrap()).unwrap();
    assert_eq!(meta["method"], "compennet++-cpu", "{meta}");
    assert_eq!(meta["calibration"]["climb"]["replaced"], "linear", "{meta}");
    // It plays on: frames keep coming after the swap.
    let a = svc.status()["frames"]["shown"].as_u64().unwrap();
    std::thread::sleep(Duration::from_millis(700));
    assert!(svc.status()["frames"]["shown"].as_u64().unwrap() > a);
    unsafe { libc::kill(svc.pid(), libc::SIGTERM) };
    assert_eq!(svc.wait_exit(20), Some(0), "log:\n{}", svc.log());
}

#[test]
fn a_climb_the_display_cannot_keep_up_with_is_not_trained() {
    if !gpu_or_skip() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let config = write_config(dir.path(), "textured-plane", 9, "", "enabled = false");
    // A refresh a billion times a second: no pass fits half a nanosecond.
    let text = std::fs::read_to_string(&config).unwrap().replace(
        "network = \"64\"",
        "network = \"64\"\nclimb = \"compennet++-res\"\nclimb_iters = 8\nrefresh_hz = 1e9",
    );
    std::fs::write(&config, text).unwrap();
    let mut svc = Service::start(&config);
    svc.wait_for("playback of the calibrated model", 300, playing);
    let start = Instant::now();
    while !svc.log().contains("is not climbed to") {
        assert!(
            start.elapsed() < Duration::from_secs(60),
            "log:\n{}",
            svc.log()
        );
        std::thread::sleep(Duration::from_millis(200));
    }
    let log = svc.log();
    assert!(
        log.contains("compennet++-res's live pass takes") && log.contains("over the 5.00e-7 ms"),
        "log:\n{log}"
    );
    assert!(
        !log.contains("training compennet++-res beside playback"),
        "log:\n{log}"
    );
    let s = svc.status();
    assert_eq!(s["model"]["method"], "linear");
    // `status` says so too.
    let climb = &s["last_climb"];
    assert_eq!(climb["method"], "compennet++-res", "{s}");
    assert_eq!(climb["installed"], false, "{s}");
    assert!(
        climb["message"]
            .as_str()
            .unwrap()
            .contains("is not climbed to"),
        "{s}"
    );
    unsafe { libc::kill(svc.pid(), libc::SIGTERM) };
    assert_eq!(svc.wait_exit(20), Some(0), "log:\n{}", svc.log());
}

#[test]
fn auto_with_closed_loop_pairs_trains_its_climb_beside_playback() {
    if !gpu_or_skip() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let config = write_config(dir.path(), "textured-plane", 8, "", "enabled = false");
    // `auto` with 12 closed-loop pairs waits for them to train its climb's correction on;
    // any gain will do on the rig.
    let text = std::fs::read_to_string(&config).unwrap().replace(
        "network = \"64\"",
        "network = \"64\"\nmethod = \"auto\"\nclimb_iters = 8\nclimb_gain_db = -100.0",
    );
    std::fs::write(&config, text).unwrap();
    let mut svc = Service::start(&config);
    let s = svc.wait_for("the climbed model playing", 300, |s| {
        playing(s) && s["model"]["method"] == "compennet++-res"
    });
    assert_eq!(s["calibrations"], 1, "{s}");
    // The refit on the closed-loop pairs ran on the training thread: no model played yet.
    assert!(
        svc.log().contains("training auto on the closed-loop pairs"),
        "log:\n{}",
        svc.log()
    );
    let model = dir.path().join("state/model");
    let meta = |m: &Path| -> Value {
        serde_json::from_slice(&std::fs::read(m.join("model.json")).unwrap()).unwrap()
    };
    let m = meta(&model);
    let retrained = &m["training"]["auto"]["retrained"];
    assert_eq!(retrained["pairs"], 24, "{m}");
    assert_eq!(retrained["after_judgement"], false, "{m}");
    assert!(m["training"]["auto"].get("loop_held_out").is_none(), "{m}");
    assert_eq!(
        m["training"]["auto"]["closed_loop"][0]["method"], "compennet++-res",
        "{m}"
    );
    assert_eq!(m["calibration"]["loop_pairs"], 12, "{m}");

    // A recalibration: while the refit trains, the installed model plays on.
    assert_eq!(svc.ask(r#"{"cmd":"recalibrate"}"#)["ok"], true);
    svc.wait_for("the second calibration installed", 300, |s| {
        s["calibrations"] == 2 && playing(s)
    });
    assert!(
        svc.log().contains(
            "training auto on the closed-loop pairs beside playback of the current model"
        ),
        "log:\n{}",
        svc.log()
    );
    assert_eq!(meta(&model)["training"]["auto"]["retrained"]["pairs"], 24);
    unsafe { libc::kill(svc.pid(), libc::SIGTERM) };
    assert_eq!(svc.wait_exit(20), Some(0), "log:\n{}", svc.log());
}

/// [`write_config`] for the window rig (`[rig] kind = "window"`) and a 200×150 Xvfb screen to
/// show it on; None (the test is skipped, saying why) without a GPU adapter or Xvfb.
fn window_config(
    dir: &Path,
    scene: &str,
    seed: u64,
    rig: &str,
    monitoring: &str,
) -> Option<(crate::window::Xvfb, PathBuf)> {
    crate::common::gpu()?;
    let x = crate::window::Xvfb::start(200, 150)?;
    let config = write_config(dir, scene, seed, rig, monitoring);
    let text = std::fs::read_to_string(&config)
        .unwrap()
        .replace("kind = \"virtual\"", "kind = \"window\"");
    std::fs::write(&config, text).unwrap();
    Some((x, config))
}

/// The service on the window rig under Xvfb: the real projector window on this thread, and a
/// camera on its own clock and thread (the window rig's virtual camera, looking at what the
/// window presented, with the scene's latency), as with a V4L2 camera. It calibrates, plays and
/// monitors: a still picture is scored, content that changes every frame is never seen alone
/// (the checks are counted as unseen, none is scored).
#[test]
fn the_service_monitors_through_a_camera_on_its_own_clock_under_xvfb() {
    let dir = tempfile::tempdir().unwrap();
    let Some((x, config)) = window_config(dir.path(), "textured-plane", 17, "", "") else {
        return;
    };
    let mut svc = Service::start_on(&config, Some(&x.display));
    let s = svc.wait_for("playback after the first calibration", 300, playing);
    assert_eq!(s["rig"], "window:textured-plane", "{s}");
    assert_eq!(s["model"]["verification"]["passed"], true, "{s}");
    let verified = s["model"]["verification"]["psnr"].as_f64().unwrap();

    // Bars, repeated at 30 fps: the same content stays up, so the camera sees it alone.
    let s = svc.wait_for("monitoring checks on the bars", 90, |s| {
        s["monitoring"]["checks"].as_u64().unwrap_or(0) >= 3
    });
    let psnr = s["monitoring"]["psnr"].as_f64().unwrap();
    let baseline = s["monitoring"]["baseline_psnr"].as_f64().unwrap();
    // The camera saw the intended frame, and every check saw it alike. (The virtual rig, whose
    // camera sees each frame by construction, scores these bars at 22.6 dB for this scene and
    // seed, below the 28.4 dB verified on the calibration's test images: saturated bars lie
    // partly outside what the projector can reach. A view of another frame, black or the
    // previous pattern, scores under 15 dB.)
    assert!(
        psnr > 20.0 && (psnr - baseline).abs() < 0.5,
        "monitoring {psnr} dB (baseline {baseline}) with {verified} dB verified: {s}"
    );
    assert_eq!(s["monitoring"]["drift"], false, "{s}");
    assert!(svc.log().contains("camera virtual, scene"), "{}", svc.log());

    // A square moving one pixel per frame: every frame is new content, never seen alone.
    let r = svc.ask(r#"{"cmd":"play","source":"pattern:moving?size=200x150&fps=30"}"#);
    assert_eq!(r["ok"], true, "{r}");
    let moving = |s: &Value| {
        s["source"]
            .as_str()
            .is_some_and(|src| src.contains("moving"))
    };
    let unseen = |s: &Value| s["monitoring"]["unseen"].as_u64().unwrap_or(0);
    let s = svc.wait_for("an unseen check on moving content", 60, |s| {
        moving(s) && unseen(s) >= 1
    });
    let (checks, first) = (s["monitoring"]["checks"].as_u64().unwrap(), unseen(&s));
    let s = svc.wait_for("more unseen checks", 60, |s| unseen(s) >= first + 3);
    assert!(moving(&s), "{s}");
    assert_eq!(
        s["monitoring"]["checks"].as_u64().unwrap(),
        checks,
        "nothing scored on moving content: {s}"
    );
    let o = client(&["status"], &svc.socket);
    assert!(stdout(&o).contains("checks unseen"), "{}", stdout(&o));

    assert_code(&client(&["stop"], &svc.socket), 0);
    assert_eq!(svc.wait_exit(20), Some(0), "log:\n{}", svc.log());
}

/// Drift in a set: the first projector of a tiled set is bumped while the set plays; monitoring
/// of the whole set sees it, and the service calibrates the set again and serves the new one.
#[test]
fn a_set_whose_projector_moves_is_calibrated_again() {
    if !gpu_or_skip() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let o = compend(&["sim", "show", "tiled"]);
    assert_code(&o, 0);
    let mut scene: Value = serde_json::from_str(&stdout(&o)).unwrap();
    scene["drift"] = serde_json::json!({ "shift_px": [24.0, -16.0] });
    let scene_file = dir.path().join("bumped-set.json");
    std::fs::write(&scene_file, scene.to_string()).unwrap();
    let config = write_config(
        dir.path(),
        scene_file.to_str().unwrap(),
        4,
        "drift_after_s = 2.0",
        "drift_threshold_db = 2.0\non_drift = \"refit\"",
    );
    let mut svc = Service::start(&config);
    let s = svc.wait_for("a second calibration of the set after drift", 600, |s| {
        s["calibrations"].as_u64() >= Some(2) && playing(s)
    });
    assert!(s["monitoring"]["drifts"].as_u64() >= Some(1), "{s}");
    assert_eq!(s["model"]["set"]["passed"], true, "{s}");
    let log = svc.log();
    assert!(
        log.contains("virtual rig: the projector was moved")
            && log.contains("a set of projectors is refitted by calibrating it again"),
        "{log}"
    );
    // The new set's model scores near its own baseline after the move.
    let s = svc.wait_for("monitoring of the new set", 60, |s| {
        s["monitoring"]["checks"].as_u64() >= Some(2)
    });
    assert_eq!(s["monitoring"]["drift"], false, "{s}");
    unsafe { libc::kill(svc.pid(), libc::SIGTERM) };
    assert_eq!(svc.wait_exit(20), Some(0), "log:\n{}", svc.log());
}

/// A set served on windows: two monitors of an X server (Xorg's dummy driver), one
/// `[[projector]]` section each, watched by the window rig's virtual camera on its own clock.
/// The service calibrates the set on the windows, installs it and plays it on both outputs in
/// the same refresh; the status names each projector's monitor; monitoring sees the whole set
/// through the camera on its own clock (latency measured at the set's calibration).
#[test]
fn the_service_serves_a_set_on_two_monitors() {
    if crate::common::gpu().is_none() {
        return;
    }
    let Some(x) = crate::window::XDummy::start(100, 75, 2) else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    // A slightly wider view keeps the set in sight at this camera size (as
    // tests/calibrate_window.rs does).
    let mut wide = compend::rig::scene::builtin("tiled").unwrap();
    wide.camera.hfov_deg *= 1.1;
    let scene = dir.path().join("wide.json");
    std::fs::write(&scene, serde_json::to_vec(&wide).unwrap()).unwrap();
    let config = write_config(dir.path(), &scene.display().to_string(), 9, "", "");
    let text = std::fs::read_to_string(&config)
        .unwrap()
        .replace("kind = \"virtual\"", "kind = \"window\"")
        .replace("camera_size = \"160x120\"", "camera_size = \"96x72\"")
        .replace("projector = \"200x150\"\n", "")
        .replace("ntrain = 12", "ntrain = 10\nloop_images = 0")
        .replace("network = \"64\"", "network = \"32\"")
        .replace("size=200x150", "size=100x75")
        .replace(
            "[paths]\n",
            "[[projector]]\nmonitor = \"DUMMY0\"\n[[projector]]\nmonitor = \"DUMMY1\"\n\n[paths]\n",
        );
    std::fs::write(&config, text).unwrap();
    let mut svc = Service::start_on(&config, Some(&x.display));
    let s = svc.wait_for("playback of the set on its windows", 600, playing);
    assert_eq!(s["model"]["method"], "linear (a set of 2, joint)", "{s}");
    assert_eq!(s["model"]["set"]["passed"], true, "{s}");
    let p = s["projectors"].as_array().unwrap();
    let outputs: Vec<&str> = p.iter().map(|p| p["output"].as_str().unwrap()).collect();
    assert_eq!(outputs, ["DUMMY0", "DUMMY1"], "{s}");
    assert!(p.iter().all(|p| p["size"] == "100x75"), "{s}");
    assert!(
        svc.log().contains("a set of 2 projector windows"),
        "{}",
        svc.log()
    );
    // Bars held still: the camera on its own clock sees the whole set alone.
    let s = svc.wait_for("monitoring checks of the set", 120, |s| {
        s["monitoring"]["checks"].as_u64().unwrap_or(0) >= 2
    });
    let psnr = s["monitoring"]["psnr"].as_f64().unwrap();
    assert!(psnr > 15.0, "monitoring {psnr} dB: {s}");
    assert_code(&client(&["stop"], &svc.socket), 0);
    assert_eq!(svc.wait_exit(20), Some(0), "log:\n{}", svc.log());
}

/// Drift through the window rig under Xvfb: the camera on its own clock sees the bumped
/// projector, monitoring reports drift, and the service recalibrates fully through the window
/// (`on_drift = "recalibrate"`; the virtual-rig test above refits) and swaps the new model in.
#[test]
fn drift_seen_through_a_camera_on_its_own_clock_is_recalibrated_under_xvfb() {
    let dir = tempfile::tempdir().unwrap();
    let scene_file = bumped_scene(dir.path());
    let Some((x, config)) = window_config(
        dir.path(),
        scene_file.to_str().unwrap(),
        4,
        "drift_after_s = 3.0",
        "drift_threshold_db = 2.0\non_drift = \"recalibrate\"",
    ) else {
        return;
    };
    let text = std::fs::read_to_string(&config)
        .unwrap()
        .replace("pattern:bars?", "pattern:checker?");
    std::fs::write(&config, text).unwrap();
    let mut svc = Service::start_on(&config, Some(&x.display));
    let s = svc.wait_for("a recalibration after drift", 420, |s| {
        s["calibrations"].as_u64() >= Some(2) && playing(s)
    });
    assert!(s["monitoring"]["drifts"].as_u64() >= Some(1), "{s}");
    let log = svc.log();
    assert!(log.contains("the projector was moved"), "{log}");
    assert!(log.contains("drift: recalibrating"), "{log}");
    let meta: Value =
        serde_json::from_slice(&std::fs::read(dir.path().join("state/model/model.json")).unwrap())
            .unwrap();
    assert_eq!(meta["training"]["ntrain"], 24, "{meta}");
    assert_eq!(meta["calibration"]["captured"], 31, "{meta}");
    assert_eq!(
        meta["calibration"]["rig"],
        format!("window:{}", scene_file.display())
    );
    // The new model is monitored on the moved projector without drift.
    let s = svc.wait_for("monitoring of the new model", 60, |s| {
        s["monitoring"]["checks"].as_u64() >= Some(2)
    });
    assert_eq!(s["monitoring"]["drift"], false, "{s}");
    assert_code(&client(&["stop"], &svc.socket), 0);
    assert_eq!(svc.wait_exit(20), Some(0), "log:\n{}", svc.log());
}

/// On real hardware, by hand: on the projection PC (an X session with the projector as a
/// monitor, a V4L2 camera looking at the surface), run
/// `COMPEND_TEST_CAMERA=/dev/video0 COMPEND_TEST_MONITOR=1 cargo test --release --test integration service::the_service_monitors_a_real_camera -- --ignored --nocapture`.
/// The service calibrates (black/white flashes, then the patterns), plays colour bars, and
/// monitoring scores the camera's view of them: the printed status should show `checks` ≥ 3
/// with a PSNR within a few dB of the verification, `unseen` 0. Then nudge the projector or the
/// surface: within two periods (`period_s = 2`) the log says DRIFT.
#[test]
#[ignore = "needs a V4L2 camera and a projector attached as a monitor of the X session"]
fn the_service_monitors_a_real_camera() {
    let camera = std::env::var("COMPEND_TEST_CAMERA").unwrap_or_else(|_| "/dev/video0".into());
    let monitor = std::env::var("COMPEND_TEST_MONITOR").unwrap_or_else(|_| "0".into());
    let dir = tempfile::tempdir().unwrap();
    let state = dir.path().join("state");
    let socket = dir.path().join("compend.sock");
    let config = dir.path().join("compend.toml");
    std::fs::write(
        &config,
        format!(
            "[rig]\nkind = \"camera\"\ncamera = \"{camera}\"\nmonitor = \"{monitor}\"\n\
             [paths]\nstate = \"{}\"\n[calibration]\nntrain = 24\n\
             [playback]\nsource = \"pattern:bars\"\n[monitoring]\nperiod_s = 2.0\n\
             [socket]\npath = \"{}\"\n[http]\nlisten = \"127.0.0.1:0\"\n",
            state.display(),
            socket.display()
        ),
    )
    .unwrap();
    let mut svc = Service::start_on(
        &config,
        std::env::var("DISPLAY").ok().as_deref().or(Some(":0")),
    );
    let s = svc.wait_for("playback after calibration", 900, playing);
    eprintln!("{s:#}");
    let s = svc.wait_for("three monitoring checks", 120, |s| {
        s["monitoring"]["checks"].as_u64() >= Some(3)
    });
    eprintln!("{s:#}\n{}", svc.log());
    assert_eq!(s["monitoring"]["unseen"], 0, "{s}");
    assert_code(&client(&["stop"], &svc.socket), 0);
    assert_eq!(svc.wait_exit(30), Some(0), "log:\n{}", svc.log());
}
