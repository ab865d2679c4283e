//! The operator's console (`[http]`) of a running service on the virtual rig: the page, the
//! status, the metrics, the camera's images, requests with their origin in the event stream
//! and the log, and the POST defences, over real HTTP connections.

use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::os::unix::process::CommandExt;
use std::sync::mpsc;
use std::time::{Duration, Instant};

use serde_json::Value;

use crate::service::{Service, client, gpu_or_skip, playing, write_config};

/// One HTTP/1.1 exchange (`Connection: close`): the status code, the headers (lower-case
/// names) and the body.
pub(crate) fn http(
    addr: &str,
    method: &str,
    path: &str,
    headers: &[(&str, &str)],
    body: &[u8],
) -> (u16, String, Vec<u8>) {
    let mut s = TcpStream::connect(addr).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(60))).unwrap();
    let mut req = format!(
        "{method} {path} HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\nContent-Length: {}\r\n",
        body.len()
    );
    for (k, v) in headers {
        req.push_str(&format!("{k}: {v}\r\n"));
    }
    req.push_str("\r\n");
    s.write_all(req.as_bytes()).unwrap();
    s.write_all(body).unwrap();
    // Read the head, then the body by its length (chromedriver keeps the connection open),
    // by its chunks, or to the end.
    let mut all = Vec::new();
    let mut buf = [0u8; 8192];
    let split = loop {
        if let Some(i) = all.windows(4).position(|w| w == b"\r\n\r\n") {
            break i;
        }
        let n = s.read(&mut buf).unwrap();
        assert!(
            n > 0,
            "the connection closed before the end of an HTTP head"
        );
        all.extend_from_slice(&buf[..n]);
    };
    let head = String::from_utf8_lossy(&all[..split]).to_lowercase();
    let code = head.split_whitespace().nth(1).unwrap().parse().unwrap();
    let mut body = all[split + 4..].to_vec();
    let length = head
        .lines()
        .find_map(|l| l.strip_prefix("content-length:"))
        .map(|v| v.trim().parse::<usize>().unwrap());
    let chunked = head.contains("transfer-encoding: chunked");
    loop {
        let done = match length {
            Some(n) => body.len() >= n,
            None if chunked => body.ends_with(b"0\r\n\r\n"),
            None => false,
        };
        if done {
            break;
        }
        let n = s.read(&mut buf).unwrap();
        if n == 0 {
            break;
        }
        body.extend_from_slice(&buf[..n]);
    }
    if chunked {
        body = unchunk(&body);
    }
    (code, head, body)
}

fn unchunk(mut b: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    loop {
        let eol = b.windows(2).position(|w| w == b"\r\n").unwrap();
        let n = usize::from_str_radix(std::str::from_utf8(&b[..eol]).unwrap().trim(), 16).unwrap();
        if n == 0 {
            return out;
        }
        out.extend_from_slice(&b[eol + 2..eol + 2 + n]);
        b = &b[eol + 2 + n + 2..];
    }
}

/// The console's event stream, each event's JSON sent on the channel as it comes.
fn subscribe(addr: &str) -> mpsc::Receiver<Value> {
    let mut s = TcpStream::connect(addr).unwrap();
    write!(s, "GET /api/events HTTP/1.1\r\nHost: {addr}\r\n\r\n").unwrap();
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        for line in BufReader::new(s).lines() {
            let Ok(line) = line else { return };
            if let Some(data) = line.strip_prefix("data: ")
                && let Ok(v) = serde_json::from_str::<Value>(data)
                && tx.send(v).is_err()
            {
                return;
            }
        }
    });
    rx
}

/// Events from `rx` until one satisfies `want` (panics after `secs`, listing what came).
fn until(
    rx: &mpsc::Receiver<Value>,
    seen: &mut Vec<Value>,
    secs: u64,
    want: impl Fn(&Value) -> bool,
) -> Value {
    let end = Instant::now() + Duration::from_secs(secs);
    if let Some(v) = seen.iter().find(|v| want(v)) {
        return v.clone();
    }
    loop {
        let left = end.saturating_duration_since(Instant::now());
        match rx.recv_timeout(left) {
            Ok(v) => {
                seen.push(v.clone());
                if want(&v) {
                    return v;
                }
            }
            Err(_) => panic!("the event did not come within {secs} s; events: {seen:#?}"),
        }
    }
}

/// A request of the control socket's as the page sends it (`POST /api/request` with
/// `X-Compend: 1`): the HTTP status and the reply.
pub(crate) fn request(addr: &str, body: &[u8]) -> (u16, Value) {
    let (code, _, reply) = http(addr, "POST", "/api/request", &[("X-Compend", "1")], body);
    (code, json(&reply))
}

pub(crate) fn json(body: &[u8]) -> Value {
    serde_json::from_slice(body)
        .unwrap_or_else(|e| panic!("{e}: {}", String::from_utf8_lossy(body)))
}

#[test]
fn the_console_shows_the_running_service_and_drives_it() {
    if !gpu_or_skip() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let config = write_config(dir.path(), "curved", 11, "", "");
    // OSC too, its events sent to this test's own UDP port.
    let osc = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
    osc.set_read_timeout(Some(Duration::from_secs(30))).unwrap();
    let text = std::fs::read_to_string(&config).unwrap().replace(
        "[log]",
        &format!(
            "[osc]\nlisten = \"127.0.0.1:0\"\npeers = [\"{}\"]\n\n[log]",
            osc.local_addr().unwrap()
        ),
    );
    std::fs::write(&config, text).unwrap();
    let mut svc = Service::start(&config);
    // The console answers from the start, on the free port it was given.
    let s = svc.wait_for("the console's address", 60, |s| s["http"].is_string());
    let addr = s["http"].as_str().unwrap().to_string();
    let events = subscribe(&addr);
    let mut seen = Vec::new();
    // The same events on the control socket, after `subscribe` (its reply echoes the id).
    let mut sock = std::os::unix::net::UnixStream::connect(&svc.socket).unwrap();
    sock.write_all(b"{\"cmd\":\"subscribe\",\"request_id\":5}\n")
        .unwrap();
    let mut sock_lines = BufReader::new(sock.try_clone().unwrap()).lines();
    let first: Value = serde_json::from_str(&sock_lines.next().unwrap().unwrap()).unwrap();
    assert_eq!(first["ok"], true, "{first}");
    assert_eq!(first["request_id"], 5, "{first}");

    let (code, head, body) = http(&addr, "GET", "/", &[], b"");
    assert_eq!(code, 200);
    assert!(head.contains("content-type: text/html"), "{head}");
    assert!(head.contains("content-security-policy"), "{head}");
    assert!(String::from_utf8_lossy(&body).contains("<title>compend console</title>"));

    // Connections that never send a request cannot lock the console: with more of them open
    // than it serves at once, a page still gets its answer once they are closed for silence.
    let silent: Vec<TcpStream> = (0..70)
        .map(|_| TcpStream::connect(&addr).unwrap())
        .collect();
    let t = Instant::now();
    let (code, _, _) = http(&addr, "GET", "/api/status", &[], b"");
    assert_eq!(code, 200);
    assert!(t.elapsed() < Duration::from_secs(30), "{:?}", t.elapsed());
    drop(silent);
    // Calibration at start, pushed as it goes: the phases, its end, the state changes.
    until(&events, &mut seen, 300, |e| e["kind"] == "phase");
    until(&events, &mut seen, 300, |e| {
        e["kind"] == "calibration" && e["ok"] == true
    });
    until(&events, &mut seen, 300, |e| {
        e["kind"] == "state" && e["state"] == "playing"
    });
    svc.wait_for("playback", 120, playing);

    // The status as the socket gives it, and metrics a Prometheus server parses.
    let (code, _, body) = http(&addr, "GET", "/api/status", &[], b"");
    assert_eq!(code, 200);
    assert_eq!(json(&body)["calibrations"], 1);
    let (code, head, body) = http(&addr, "GET", "/metrics", &[], b"");
    assert_eq!(code, 200);
    assert!(head.contains("text/plain; version=0.0.4"), "{head}");
    let text = String::from_utf8(body).unwrap();
    let scrape = prometheus_parse::Scrape::parse(text.lines().map(|l| Ok(l.to_string()))).unwrap();
    let value = |name: &str, label: Option<(&str, &str)>| {
        scrape
            .samples
            .iter()
            .find(|s| s.metric == name && label.is_none_or(|(k, v)| s.labels.get(k) == Some(v)))
            .map(|s| s.value.clone())
            .unwrap_or_else(|| panic!("no {name} in:\n{text}"))
    };
    assert_eq!(
        value("compend_calibrations_total", None),
        prometheus_parse::Value::Counter(1.0)
    );
    assert_eq!(
        value("compend_state", Some(("state", "playing"))),
        prometheus_parse::Value::Gauge(1.0)
    );
    let compensated = value(
        "compend_model_verification_psnr_db",
        Some(("projection", "compensated")),
    );
    let prometheus_parse::Value::Gauge(db) = compensated else {
        panic!("{compensated:?}")
    };
    assert!(db > 10.0, "{text}");

    // What the camera sees, and the last monitoring check's pair with its difference.
    let (code, head, body) = http(&addr, "GET", "/api/camera.jpg", &[], b"");
    assert_eq!(code, 200, "{}", String::from_utf8_lossy(&body));
    assert!(
        head.contains("image/jpeg") && body.starts_with(&[0xFF, 0xD8]),
        "{head}"
    );
    let score = until(&events, &mut seen, 120, |e| e["kind"] == "score");
    assert!(score["psnr"].as_f64().unwrap() > 10.0, "{score}");
    for which in ["desired.jpg", "seen.jpg", "difference.jpg"] {
        let (code, _, body) = http(&addr, "GET", &format!("/api/check/{which}"), &[], b"");
        assert_eq!(code, 200, "{which}");
        let img = image::load_from_memory(&body).unwrap();
        assert_eq!((img.width(), img.height()), (160, 120), "{which}");
    }
    // Where the calibration found the surface cannot be compensated, with the shares.
    let (code, head, body) = http(&addr, "GET", "/api/model/unreachable.png", &[], b"");
    assert_eq!(code, 200, "{}", String::from_utf8_lossy(&body));
    assert!(head.contains("image/png"), "{head}");
    let map = image::load_from_memory(&body).unwrap();
    assert_eq!((map.width(), map.height()), (160, 120));
    let (_, _, body) = http(&addr, "GET", "/api/status", &[], b"");
    let share = &json(&body)["model"]["unreachable"]["unreachable_percent"];
    assert!(
        share.as_f64().is_some_and(|p| (0.0..=100.0).contains(&p)),
        "{share}"
    );
    let (_, _, body) = http(&addr, "GET", "/api/check/area.json", &[], b"");
    let area = json(&body);
    assert!(area["width"].as_u64().unwrap() > 10, "{area}");
    // The served model's field of view to lay over the camera view: clear where the projector
    // lights the surface (most of the displayable area), dimmed where it does not, an edge.
    let (code, head, body) = http(&addr, "GET", "/api/model/fov.png", &[], b"");
    assert_eq!(code, 200, "{}", String::from_utf8_lossy(&body));
    assert!(head.contains("image/png"), "{head}");
    let fov = image::load_from_memory(&body).unwrap().to_rgba8();
    assert_eq!(fov.dimensions(), (160, 120));
    let alpha = |x: u64, y: u64| fov.get_pixel(x as u32, y as u32).0[3];
    let (ax, ay) = (area["x"].as_u64().unwrap(), area["y"].as_u64().unwrap());
    let (aw, ah) = (
        area["width"].as_u64().unwrap(),
        area["height"].as_u64().unwrap(),
    );
    assert_eq!(
        alpha(ax + aw / 2, ay + ah / 2),
        0,
        "clear in the displayable area"
    );
    let kinds: std::collections::HashSet<[u8; 4]> = fov.pixels().map(|p| p.0).collect();
    assert!(kinds.contains(&[0, 229, 255, 255]), "an edge: {kinds:?}");

    // A POST without the header, or from another site's page, is refused and changes nothing.
    let pause = br#"{"cmd":"pause"}"#;
    let (code, _, _) = http(
        &addr,
        "POST",
        "/api/request",
        &[("Content-Type", "application/json")],
        pause,
    );
    assert_eq!(code, 403);
    let (code, _, _) = http(
        &addr,
        "POST",
        "/api/request",
        &[("X-Compend", "1"), ("Origin", "http://evil.example")],
        pause,
    );
    assert_eq!(code, 403);
    assert_eq!(svc.status()["state"], "playing");
    // With it: paused, and said with its origin in the stream and the log.
    let (code, reply) = request(&addr, pause);
    assert_eq!(code, 200);
    assert_eq!(reply["ok"], true, "{reply}");
    let e = until(&events, &mut seen, 30, |e| {
        e["kind"] == "request" && e["ok"] == true
    });
    assert!(
        e["origin"].as_str().unwrap().starts_with("http 127.0.0.1:"),
        "{e}"
    );
    assert!(e["text"].as_str().unwrap().contains("pause"), "{e}");
    until(&events, &mut seen, 30, |e| {
        e["kind"] == "state" && e["state"] == "paused"
    });
    let paused = sock_lines
        .by_ref()
        .map(|l| serde_json::from_str::<Value>(&l.unwrap()).unwrap())
        .find(|v| v["event"]["kind"] == "request" && v["event"]["ok"] == true)
        .expect("the socket's subscriber sees the request");
    assert!(
        paused["event"]["text"].as_str().unwrap().contains("pause"),
        "{paused}"
    );
    drop(sock_lines);
    drop(sock);
    // A request id is echoed over HTTP too, and a bad request still names its id.
    let (code, reply) = request(&addr, br#"{"cmd":"status","request_id":"q1"}"#);
    assert_eq!(code, 200);
    assert_eq!(reply["request_id"], "q1");
    let (code, reply) = request(&addr, br#"{"cmd":"fly","request_id":9}"#);
    assert_eq!(code, 400);
    assert_eq!(reply["request_id"], 9);
    // The same from the socket names the user.
    let o = client(&["play"], &svc.socket);
    assert_eq!(
        o.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let e = until(&events, &mut seen, 30, |e| {
        e["kind"] == "request"
            && e["origin"]
                .as_str()
                .is_some_and(|o| o.starts_with("unix uid "))
    });
    assert!(e["text"].as_str().unwrap().contains("play"), "{e}");
    // The play is answered before the playback is back: wait for it, so that the pause below
    // changes the state.
    svc.wait_for("playback again", 60, playing);
    // OSC: a button's press pauses (its release does nothing), the sender hears the reply, the
    // peers the new state, and the stream names the origin.
    let osc_addr = svc.status()["osc"].as_str().unwrap().to_string();
    let send = |addr: &str, args: Vec<rosc::OscType>| {
        let p = rosc::OscPacket::Message(rosc::OscMessage {
            addr: addr.into(),
            args,
        });
        osc.send_to(&rosc::encoder::encode(&p).unwrap(), &osc_addr)
            .unwrap();
    };
    // The reply (sent by the request's task) and the peers' events (sent by theirs) may come
    // in either order: a message looked for later is kept, not dropped.
    let kept = std::cell::RefCell::new(Vec::<rosc::OscMessage>::new());
    let heard = |want: &dyn Fn(&rosc::OscMessage) -> bool| -> rosc::OscMessage {
        let found = kept.borrow().iter().position(want);
        if let Some(i) = found {
            return kept.borrow_mut().remove(i);
        }
        let mut buf = [0u8; 65536];
        loop {
            let (n, _) = osc.recv_from(&mut buf).expect("an OSC message within 30 s");
            if let (_, rosc::OscPacket::Message(m)) = rosc::decoder::decode_udp(&buf[..n]).unwrap()
            {
                if want(&m) {
                    return m;
                }
                kept.borrow_mut().push(m);
            }
        }
    };
    // What the peers were sent before (the HTTP pause's state included) is read and dropped.
    osc.set_nonblocking(true).unwrap();
    let mut buf = [0u8; 65536];
    while osc.recv_from(&mut buf).is_ok() {}
    osc.set_nonblocking(false).unwrap();
    send("/compend/pause", vec![rosc::OscType::Float(1.0)]);
    send("/compend/pause", vec![rosc::OscType::Float(0.0)]);
    let r = heard(&|m| m.addr == "/compend/reply");
    assert_eq!(r.args[0], rosc::OscType::Int(1), "{r:?}");
    heard(&|m| m.addr == "/compend/state" && m.args == [rosc::OscType::String("paused".into())]);
    let e = until(&events, &mut seen, 30, |e| {
        e["kind"] == "request" && e["origin"].as_str().is_some_and(|o| o.starts_with("osc "))
    });
    assert!(e["text"].as_str().unwrap().contains("pause"), "{e}");
    send("/compend/nope", vec![]);
    let r = heard(&|m| m.addr == "/compend/reply");
    assert_eq!(r.args[0], rosc::OscType::Int(0), "{r:?}");
    send("/compend/resume", vec![]);
    heard(&|m| m.addr == "/compend/state" && m.args == [rosc::OscType::String("playing".into())]);
    // The setup view: a pattern up as it is, the camera's figures in the status; a bad
    // pattern is refused with the ones there are; play leaves it.
    let (code, reply) = request(&addr, br#"{"cmd":"setup","pattern":"moire"}"#);
    assert_eq!(code, 400);
    assert!(
        reply.to_string().contains("grid, crosshair, white, black"),
        "{reply}"
    );
    let mut figures = |pattern: &str| {
        let body = format!(r#"{{"cmd":"setup","pattern":"{pattern}"}}"#);
        let (code, reply) = request(&addr, body.as_bytes());
        assert_eq!(code, 200);
        assert_eq!(reply["ok"], true, "{reply}");
        let s = svc.wait_for("the setup figures", 60, |s| {
            s["state"] == "setup"
                && s["setup"]["pattern"] == pattern
                && s["setup"]["frames"].as_u64().unwrap_or(0) >= 3
        });
        s["setup"].clone()
    };
    let black = figures("black");
    let grid = figures("grid");
    assert!(
        grid["sharpness"].as_f64().unwrap() > black["sharpness"].as_f64().unwrap(),
        "{grid} {black}"
    );
    let o = client(&["play"], &svc.socket);
    assert_eq!(
        o.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let s = svc.wait_for("playback after setup", 60, playing);
    assert!(s.get("setup").is_none(), "{s}");
    // A late page gets what happened from the kept log.
    let (_, _, body) = http(&addr, "GET", "/api/log", &[], b"");
    let log = json(&body);
    assert!(
        log["events"]
            .as_array()
            .unwrap()
            .iter()
            .any(|e| e["kind"] == "calibration"),
        "{log}"
    );
    assert!(!log["scores"].as_array().unwrap().is_empty(), "{log}");
    let text = svc.log();
    assert!(text.contains("request from http 127.0.0.1:"), "{text}");
    assert!(text.contains("request from unix uid"), "{text}");

    let o = client(&["stop"], &svc.socket);
    assert_eq!(o.status.code(), Some(0));
    assert_eq!(svc.wait_exit(60), Some(0), "{}", svc.log());
}

/// A WebDriver session of Debian's chromium, headless, through chromedriver on a free port;
/// both end with it.
struct Browser {
    driver: std::process::Child,
    addr: String,
    session: String,
}

impl Browser {
    fn start() -> Self {
        let port = std::net::TcpListener::bind("127.0.0.1:0")
            .unwrap()
            .local_addr()
            .unwrap()
            .port();
        // Its own process group, so that chromium goes with it however the test ends.
        let driver = std::process::Command::new("chromedriver")
            .process_group(0)
            .arg(format!("--port={port}"))
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::null())
            .spawn()
            .expect("chromedriver runs (scripts/deps.sh installs chromium and chromium-driver)");
        let addr = format!("127.0.0.1:{port}");
        let start = Instant::now();
        while TcpStream::connect(&addr).is_err() {
            assert!(
                start.elapsed() < Duration::from_secs(30),
                "chromedriver did not start"
            );
            std::thread::sleep(Duration::from_millis(100));
        }
        let mut b = Browser {
            driver,
            addr,
            session: String::new(),
        };
        // The flags keep chromium off the network this machine does not have, and out of any
        // profile but a fresh one.
        let profile = tempfile::tempdir().unwrap().keep();
        let caps = serde_json::json!({"capabilities": {"alwaysMatch": {"goog:chromeOptions": {
            "binary": "/usr/bin/chromium",
            "args": ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
                     "--no-first-run", "--disable-background-networking",
                     "--disable-component-update", "--disable-sync", "--window-size=1400,1000",
                     format!("--user-data-dir={}", profile.display())]
        }}}});
        let v = b.call("POST", "/session", Some(caps));
        b.session = v["sessionId"].as_str().expect("a session").to_string();
        b
    }

    fn call(&self, method: &str, path: &str, body: Option<Value>) -> Value {
        let body = body.map(|b| b.to_string()).unwrap_or_default();
        let (code, _, out) = http(
            &self.addr,
            method,
            path,
            &[("Content-Type", "application/json")],
            body.as_bytes(),
        );
        let v = json(&out);
        assert_eq!(code, 200, "WebDriver {method} {path}: {v}");
        v["value"].clone()
    }

    fn go(&self, url: &str) {
        self.call(
            "POST",
            &format!("/session/{}/url", self.session),
            Some(serde_json::json!({ "url": url })),
        );
    }

    fn run(&self, script: &str) -> Value {
        self.call(
            "POST",
            &format!("/session/{}/execute/sync", self.session),
            Some(serde_json::json!({ "script": script, "args": [] })),
        )
    }

    /// Runs `script` until it returns true (panics after `secs`, with `what`).
    fn wait(&self, what: &str, secs: u64, script: &str) {
        let start = Instant::now();
        while self.run(script) != Value::Bool(true) {
            assert!(
                start.elapsed() < Duration::from_secs(secs),
                "the page never showed {what}"
            );
            std::thread::sleep(Duration::from_millis(200));
        }
    }

    fn click(&self, css: &str) {
        let e = self.call(
            "POST",
            &format!("/session/{}/element", self.session),
            Some(serde_json::json!({ "using": "css selector", "value": css })),
        );
        let id = e
            .as_object()
            .and_then(|o| o.values().next())
            .and_then(|v| v.as_str())
            .expect("an element id")
            .to_string();
        self.call(
            "POST",
            &format!("/session/{}/element/{id}/click", self.session),
            Some(serde_json::json!({})),
        );
    }

    fn screenshot(&self) -> Vec<u8> {
        use base64::Engine;
        let v = self.call(
            "GET",
            &format!("/session/{}/screenshot", self.session),
            None,
        );
        base64::engine::general_purpose::STANDARD
            .decode(v.as_str().unwrap())
            .unwrap()
    }
}

impl Drop for Browser {
    fn drop(&mut self) {
        if !self.session.is_empty() {
            let _ = http(
                &self.addr,
                "DELETE",
                &format!("/session/{}", self.session),
                &[],
                b"",
            );
        }
        // SAFETY: killpg with the group chromedriver leads and a valid signal number has no
        // memory effects.
        unsafe { libc::killpg(self.driver.id() as i32, libc::SIGKILL) };
        let _ = self.driver.wait();
    }
}

/// A sum over the camera image's pixels as the page shows it (drawn into a canvas).
const CAMERA_SUM: &str = "const i = document.getElementById('cam'); \
    if (!i.naturalWidth) return -1; \
    const c = document.createElement('canvas'); c.width = i.naturalWidth; c.height = i.naturalHeight; \
    const g = c.getContext('2d'); g.drawImage(i, 0, 0); \
    const d = g.getImageData(0, 0, c.width, c.height).data; let s = 0; \
    for (let k = 0; k < d.length; k += 7) s += d[k] * (k % 13); return s;";

#[test]
fn the_console_page_in_chromium_shows_the_camera_and_recalibrates() {
    if !gpu_or_skip() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let config = write_config(dir.path(), "textured-plane", 12, "", "");
    let mut svc = Service::start(&config);
    let s = svc.wait_for("playback", 300, playing);
    let url = format!("http://{}/", s["http"].as_str().unwrap());
    let browser = Browser::start();
    browser.go(&url);
    browser.wait(
        "the state",
        60,
        "return document.getElementById('state').textContent === 'playing'",
    );
    // The camera's view arrives and changes (the rig's camera has noise of its own).
    browser.wait(
        "a camera frame",
        60,
        "return document.getElementById('cam').naturalWidth > 0",
    );
    let first = browser.run(CAMERA_SUM);
    let start = Instant::now();
    loop {
        std::thread::sleep(Duration::from_millis(300));
        if browser.run(CAMERA_SUM) != first {
            break;
        }
        assert!(
            start.elapsed() < Duration::from_secs(30),
            "the camera image never changed"
        );
    }
    browser.wait(
        "the verification",
        30,
        "return document.getElementById('modelbox').textContent.includes('compensated')",
    );
    // The setup view from the page: the crosshair up, its figures shown.
    browser.click("button[data-setup=crosshair]");
    browser.wait(
        "the setup figures",
        60,
        "return document.getElementById('setupbox').textContent.includes('sharpness') && document.getElementById('state').textContent === 'setup'",
    );
    // Recalibrate from the page (it leaves the setup view): the phases advance in its log, a
    // second calibration ends and is shown, and playback comes back.
    browser.click("button[data-cmd=recalibrate]");
    browser.wait(
        "the request's reply",
        30,
        "return !document.getElementById('reply').textContent.startsWith('asking')",
    );
    let reply = browser.run("return document.getElementById('reply').textContent");
    assert!(!reply.as_str().unwrap().is_empty(), "{reply}");
    browser.wait(
        "a calibration phase",
        120,
        "return [...document.querySelectorAll('#log li')].some(l => /calibration: \\w/.test(l.textContent) && !/installed/.test(l.textContent))",
    );
    browser.wait(
        "the second calibration's end",
        300,
        "return [...document.querySelectorAll('#log li')].filter(l => l.textContent.includes('calibration installed')).length >= 2",
    );
    browser.wait(
        "playback again",
        120,
        "return document.getElementById('state').textContent === 'playing'",
    );
    assert_eq!(svc.status()["calibrations"], 2);
    let origin = browser.run(
        "return [...document.querySelectorAll('#log li')].map(l => l.textContent).filter(t => t.includes('recalibrate'))",
    );
    assert!(origin.to_string().contains("http 127.0.0.1:"), "{origin}");
    // The page as it looks, saved for people to see, and not blank.
    let png = browser.screenshot();
    let shot = dir.path().join("console.png");
    std::fs::write(&shot, &png).unwrap();
    if let Ok(keep) = std::env::var("COMPEND_TEST_SCREENSHOTS") {
        let _ = std::fs::create_dir_all(&keep);
        let _ = std::fs::copy(&shot, std::path::Path::new(&keep).join("console.png"));
    }
    let img = image::load_from_memory(&png).unwrap().to_rgb8();
    let mut colours = std::collections::HashSet::new();
    for p in img.pixels().step_by(17) {
        colours.insert(p.0);
    }
    assert!(
        colours.len() > 200,
        "a screenshot of {} colours",
        colours.len()
    );
    drop(browser);
    let o = client(&["stop"], &svc.socket);
    assert_eq!(o.status.code(), Some(0));
    assert_eq!(svc.wait_exit(60), Some(0), "{}", svc.log());
}

#[test]
fn the_console_speaks_https_with_a_certificate_and_refuses_bad_ones() {
    if !gpu_or_skip() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let (cert, key) = (dir.path().join("cert.pem"), dir.path().join("key.pem"));
    let ca = dir.path().join("ca.pem");
    // A certificate authority of the test's own, and the console's certificate signed by it.
    let openssl = |args: &[&str]| {
        let ec = [
            "-newkey",
            "ec",
            "-pkeyopt",
            "ec_paramgen_curve:P-256",
            "-nodes",
            "-days",
            "1",
        ];
        let o = std::process::Command::new("openssl")
            .args(["req", "-x509"])
            .args(ec)
            .args(args)
            .current_dir(dir.path())
            .output()
            .expect("openssl runs");
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    };
    openssl(&[
        "-subj",
        "/CN=test CA",
        "-keyout",
        "ca-key.pem",
        "-out",
        "ca.pem",
    ]);
    openssl(&[
        "-CA",
        "ca.pem",
        "-CAkey",
        "ca-key.pem",
        "-subj",
        "/CN=localhost",
        "-addext",
        "subjectAltName=DNS:localhost",
        "-addext",
        "basicConstraints=critical,CA:FALSE",
        "-keyout",
        "key.pem",
        "-out",
        "cert.pem",
    ]);
    let config = write_config(dir.path(), "textured-plane", 13, "", "");
    let with_tls = |cert: &std::path::Path| {
        let text = std::fs::read_to_string(&config).unwrap().replace(
            "[http]\n",
            &format!(
                "[http]\ntls_cert = \"{}\"\ntls_key = \"{}\"\n",
                cert.display(),
                key.display()
            ),
        );
        std::fs::write(&config, text).unwrap();
    };
    // A certificate file that holds something else: refused at start, naming the key.
    let junk = dir.path().join("junk.pem");
    std::fs::write(&junk, "not a certificate\n").unwrap();
    let original = std::fs::read_to_string(&config).unwrap();
    with_tls(&junk);
    let o = crate::common::compend(&["serve", "--config", config.to_str().unwrap()]);
    assert_eq!(
        o.status.code(),
        Some(2),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(
        e.contains("[http] tls_cert") && e.contains("junk.pem"),
        "{e}"
    );
    std::fs::write(&config, original).unwrap();
    with_tls(&cert);
    let mut svc = Service::start(&config);
    let s = svc.wait_for("the console's address", 60, |s| s["http"].is_string());
    let addr = s["http"].as_str().unwrap().to_string();
    // A client that trusts the certificate gets the status over TLS.
    use rustls::pki_types::pem::PemObject;
    let mut roots = rustls::RootCertStore::empty();
    for c in rustls::pki_types::CertificateDer::pem_file_iter(&ca).unwrap() {
        roots.add(c.unwrap()).unwrap();
    }
    let trusting = std::sync::Arc::new(
        rustls::ClientConfig::builder_with_provider(std::sync::Arc::new(
            rustls::crypto::ring::default_provider(),
        ))
        .with_safe_default_protocol_versions()
        .unwrap()
        .with_root_certificates(roots)
        .with_no_client_auth(),
    );
    let conn = rustls::ClientConnection::new(trusting, "localhost".try_into().unwrap()).unwrap();
    let tcp = TcpStream::connect(&addr).unwrap();
    tcp.set_read_timeout(Some(Duration::from_secs(30))).unwrap();
    let mut tls = rustls::StreamOwned::new(conn, tcp);
    write!(
        tls,
        "GET /api/status HTTP/1.1\r\nHost: localhost\r\nConnection: close\r\n\r\n"
    )
    .unwrap();
    let mut reply = Vec::new();
    let _ = tls.read_to_end(&mut reply);
    let text = String::from_utf8_lossy(&reply);
    assert!(text.starts_with("HTTP/1.1 200"), "{text}");
    assert!(
        text.contains("\"rig\":\"virtual:textured-plane\""),
        "{text}"
    );
    // Plain HTTP on that port gets no page.
    let mut plain = TcpStream::connect(&addr).unwrap();
    plain
        .set_read_timeout(Some(Duration::from_secs(15)))
        .unwrap();
    write!(plain, "GET /api/status HTTP/1.1\r\nHost: x\r\n\r\n").unwrap();
    let mut got = Vec::new();
    let _ = plain.read_to_end(&mut got);
    assert!(!String::from_utf8_lossy(&got).contains("\"rig\""));
    let o = client(&["stop"], &svc.socket);
    assert_eq!(o.status.code(), Some(0));
    assert_eq!(svc.wait_exit(60), Some(0), "{}", svc.log());
}
