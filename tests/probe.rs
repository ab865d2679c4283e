//! The standing hostile probe of `compend serve` and `compend calibrate` on the virtual rig
//! (issue 50): malformed, duplicate-key and oversized requests on every listener (the Unix
//! socket, the TCP port, the console's HTTP and OSC), floods of wrong tokens, slow and silent
//! clients, hostile sources, kill -9 at seeded moments with the installed model's SHA-256 and
//! loadability checked after each, a full disk, an unwritable state folder as an unprivileged
//! user, and configurations `config check` must refuse as `serve` does.
//!
//! Each probe is tallied with its outcome; a test fails naming every probe that did not hold
//! (and any that lost data), and prints the tally, which docs/probe.md records.

use std::io::{BufRead, BufReader, Read, Write};
use std::net::{TcpStream, UdpSocket};
use std::os::unix::net::UnixStream;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use serde_json::Value;
use sha2::Digest;

use crate::common::{assert_code, compend, stderr};
use crate::service::{Service, client, gpu_or_skip, playing, write_config};

/// Probes and their outcomes; panics at the end naming those that did not hold.
struct Tally {
    what: &'static str,
    held: Vec<String>,
    failed: Vec<String>,
}

impl Tally {
    fn new(what: &'static str) -> Self {
        Self {
            what,
            held: Vec::new(),
            failed: Vec::new(),
        }
    }

    /// Records probe `name`: held when `ok`, else failed with `why`.
    fn check(&mut self, name: &str, ok: bool, why: impl std::fmt::Display) {
        if ok {
            self.held.push(name.to_string());
        } else {
            self.failed.push(format!("{name}: {why}"));
        }
    }

    fn finish(self, log: &str) {
        eprintln!(
            "probe tally ({}): {} probes, {} held, {} did not",
            self.what,
            self.held.len() + self.failed.len(),
            self.held.len(),
            self.failed.len()
        );
        assert!(
            self.failed.is_empty(),
            "{} probe(s) did not hold:\n{}\nservice log:\n{log}",
            self.failed.len(),
            self.failed.join("\n")
        );
    }
}

/// SHA-256 of a model folder's files (name and bytes, in name order); None when it holds no
/// model.
fn model_digest(dir: &Path) -> Option<String> {
    let mut names: Vec<PathBuf> = std::fs::read_dir(dir)
        .ok()?
        .map(|e| e.unwrap().path())
        .filter(|p| p.is_file())
        .collect();
    names.sort();
    if !names.iter().any(|p| p.ends_with("model.json")) {
        return None;
    }
    let mut h = sha2::Sha256::new();
    for p in names {
        h.update(p.file_name().unwrap().as_encoded_bytes());
        h.update(std::fs::read(&p).unwrap());
    }
    Some(format!("{:x}", h.finalize()))
}

/// Whether the model in `dir` loads (`compend inspect` reads it whole).
fn loads(dir: &Path) -> bool {
    compend::model::Model::load(dir).is_ok()
}

/// One line to the Unix socket `socket`, and the reply line (None: closed without one).
fn unix_line(socket: &Path, line: &[u8]) -> Option<String> {
    let mut s = UnixStream::connect(socket).ok()?;
    s.set_read_timeout(Some(Duration::from_secs(30))).ok()?;
    s.write_all(line).ok()?;
    s.write_all(b"\n").ok()?;
    let mut reply = String::new();
    BufReader::new(s).read_line(&mut reply).ok()?;
    (!reply.is_empty()).then_some(reply)
}

/// One line to the TCP port, and the reply line.
fn tcp_line(port: u16, line: &[u8]) -> Option<String> {
    let mut s = TcpStream::connect(("127.0.0.1", port)).ok()?;
    s.set_read_timeout(Some(Duration::from_secs(30))).ok()?;
    s.write_all(line).ok()?;
    s.write_all(b"\n").ok()?;
    let mut reply = String::new();
    BufReader::new(s).read_line(&mut reply).ok()?;
    (!reply.is_empty()).then_some(reply)
}

fn refused(reply: &Option<String>) -> bool {
    reply
        .as_deref()
        .and_then(|r| serde_json::from_str::<Value>(r.trim()).ok())
        .is_some_and(|v| v["ok"] == false && v["error"].is_string())
}

/// The address after `marker` in the service's log (`control port: listening on ADDR`).
fn logged_addr(svc: &Service, marker: &str) -> String {
    let text = svc.log();
    let line = text
        .lines()
        .find(|l| l.contains(marker))
        .unwrap_or_else(|| panic!("no `{marker}` in the log:\n{text}"));
    let rest = &line[line.find(marker).unwrap() + marker.len()..];
    rest.split_whitespace()
        .next()
        .unwrap()
        .trim_end_matches('/')
        .to_string()
}

/// Threads of process `pid`.
fn threads(pid: u32) -> usize {
    std::fs::read_to_string(format!("/proc/{pid}/status"))
        .unwrap()
        .lines()
        .find_map(|l| l.strip_prefix("Threads:"))
        .unwrap()
        .trim()
        .parse()
        .unwrap()
}

fn shown(svc: &Service) -> u64 {
    svc.status()["frames"]["shown"].as_u64().unwrap_or(0)
}

/// Whether the picture goes on: frames shown grow over half a second, still playing `source`.
fn still_playing(svc: &Service, source: &str) -> Result<(), String> {
    let a = shown(svc);
    std::thread::sleep(Duration::from_millis(500));
    let s = svc.status();
    let b = s["frames"]["shown"].as_u64().unwrap_or(0);
    if s["state"] != "playing" || b <= a || s["source"] != source {
        return Err(format!("not playing {source} on: {a} → {b} shown; {s}"));
    }
    Ok(())
}

#[test]
fn hostile_requests_and_sources_get_clean_refusals_and_the_picture_plays_on() {
    if !gpu_or_skip() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let config = write_config(dir.path(), "curved", 4, "", "");
    let token = "0f1e2d3c4b5a69788796a5b4c3d2e1f0";
    let token_file = dir.path().join("tcp-token");
    std::fs::write(&token_file, format!("{token}\n")).unwrap();
    let text = std::fs::read_to_string(&config).unwrap().replace(
        "[socket]\n",
        &format!(
            "[osc]\nlisten = \"127.0.0.1:0\"\n\n[socket]\ntcp = \"127.0.0.1:0\"\ntcp_token_file = \"{}\"\n",
            token_file.display()
        ),
    );
    std::fs::write(&config, text).unwrap();
    let mut svc = Service::start(&config);
    svc.wait_for("playback after the first calibration", 300, playing);
    let model = dir.path().join("state/model");
    let digest = model_digest(&model).expect("a model installed");
    let port: u16 = logged_addr(&svc, "control port: listening on ")
        .rsplit(':')
        .next()
        .unwrap()
        .parse()
        .unwrap();
    let http_addr = svc.status()["http"].as_str().unwrap().to_string();
    let osc_addr = svc.status()["osc"].as_str().unwrap().to_string();
    let source = svc.status()["source"].as_str().unwrap().to_string();
    let mut t = Tally::new("requests and sources");

    // Malformed requests on the Unix socket: each refused, the connection answered.
    let big = vec![b'x'; 200_000];
    let deep = format!("{}{}", "[".repeat(10_000), "]".repeat(10_000));
    let unix_probes: Vec<(&str, Vec<u8>)> = vec![
        ("unix: not JSON", b"status please".to_vec()),
        ("unix: not UTF-8", vec![0xff, 0xfe, b'{', b'}']),
        ("unix: empty line", Vec::new()),
        ("unix: 200 kB line", big.clone()),
        ("unix: nested 10000 deep", deep.clone().into_bytes()),
        (
            "unix: cmd given twice",
            br#"{"cmd":"status","cmd":"stop"}"#.to_vec(),
        ),
        ("unix: unknown cmd", br#"{"cmd":"format_disk"}"#.to_vec()),
        (
            "unix: unknown field",
            br#"{"cmd":"pause","now":true}"#.to_vec(),
        ),
        (
            "unix: request_id of 1000 bytes",
            format!(r#"{{"cmd":"status","request_id":"{}"}}"#, "i".repeat(1000)).into_bytes(),
        ),
        (
            "unix: a NUL in a path",
            br#"{"cmd":"model","path":"/tmp/a\u0000b"}"#.to_vec(),
        ),
        (
            "unix: seek to NaN",
            br#"{"cmd":"seek","position_s":"NaN"}"#.to_vec(),
        ),
        (
            "unix: a gst: pipeline from a client",
            br#"{"cmd":"play","source":"gst:filesrc location=/etc/shadow ! fakesink"}"#.to_vec(),
        ),
    ];
    for (name, line) in &unix_probes {
        let r = unix_line(&svc.socket, line);
        t.check(name, refused(&r), format!("{r:?}"));
    }

    // The TCP port: no token, a wrong one, the right one after a wrong one, a command given
    // twice with the right token (it must not stop), oversized.
    let right = |extra: &str| format!(r#"{{"cmd":"status","token":"{token}"{extra}}}"#);
    let tcp_probes: Vec<(&str, String)> = vec![
        ("tcp: no token", r#"{"cmd":"status"}"#.to_string()),
        (
            "tcp: a wrong token",
            r#"{"cmd":"status","token":"ffffffffffffffffffffffffffffffff"}"#.to_string(),
        ),
        (
            "tcp: a wrong token, then the right one",
            format!(
                r#"{{"cmd":"status","token":"ffffffffffffffffffffffffffffffff","token":"{token}"}}"#
            ),
        ),
        (
            "tcp: stop given twice with the right token",
            format!(r#"{{"cmd":"status","cmd":"stop","token":"{token}"}}"#),
        ),
        (
            "tcp: the token as a number",
            r#"{"cmd":"status","token":12}"#.to_string(),
        ),
        ("tcp: unknown field", right(r#","more":1"#)),
        ("tcp: 200 kB line", "y".repeat(200_000)),
    ];
    for (name, line) in &tcp_probes {
        let r = tcp_line(port, line.as_bytes());
        t.check(name, refused(&r), format!("{r:?}"));
    }
    let alive = unix_line(&svc.socket, br#"{"cmd":"status"}"#);
    let on = alive
        .as_deref()
        .is_some_and(|r| r.contains(r#""state":"playing""#));
    t.check(
        "tcp: still running after the duplicate stop",
        on,
        format!("{alive:?}"),
    );
    if !on {
        return t.finish(&svc.log());
    }

    // A flood of wrong tokens: backed off (the token no longer looked at), a few log lines
    // only, and the right token taken once the backoff is over.
    let port_lines = |log: &str| log.lines().filter(|l| l.contains("control port")).count();
    let lines_before = port_lines(&svc.log());
    let (mut sent, mut backed) = (0, 0);
    let flood = Instant::now();
    while flood.elapsed() < Duration::from_secs(2) {
        let r = tcp_line(
            port,
            br#"{"cmd":"status","token":"eeeeeeeeeeeeeeeeeeeeeeeeeeeeeeee"}"#,
        );
        sent += 1;
        if r.as_deref()
            .is_some_and(|r| r.contains("refused without a look"))
        {
            backed += 1;
        }
    }
    let logged = port_lines(&svc.log()) - lines_before;
    t.check(
        "tcp: a flood of wrong tokens is backed off",
        backed > 0 && backed + 20 >= sent,
        format!("{backed} of {sent} backed off"),
    );
    t.check(
        "tcp: a flood of wrong tokens is not a line each",
        logged <= 4,
        format!("{logged} log lines for {sent} tries"),
    );
    let waited = Instant::now();
    let mut let_in = false;
    while waited.elapsed() < Duration::from_secs(20) {
        let r = tcp_line(port, right("").as_bytes());
        if r.as_deref().is_some_and(|r| r.contains(r#""ok":true"#)) {
            let_in = true;
            break;
        }
        std::thread::sleep(Duration::from_millis(500));
    }
    t.check(
        "tcp: the right token is taken after the backoff",
        let_in,
        "refused for 20 s",
    );

    // The console: malformed and duplicate-key requests, an oversized body, a path that is not
    // there.
    let http_probes: Vec<(&str, Vec<u8>)> = vec![
        ("http: not JSON", b"{".to_vec()),
        (
            "http: cmd given twice",
            br#"{"cmd":"status","cmd":"stop"}"#.to_vec(),
        ),
        ("http: 200 kB body", big.clone()),
        ("http: nested 10000 deep", deep.into_bytes()),
    ];
    for (name, body) in &http_probes {
        let (code, _, reply) = crate::console::http(
            &http_addr,
            "POST",
            "/api/request",
            &[("X-Compend", "1")],
            body,
        );
        t.check(
            name,
            (400..500).contains(&code) || String::from_utf8_lossy(&reply).contains("\"ok\":false"),
            format!("{code} {}", String::from_utf8_lossy(&reply)),
        );
    }
    let (code, _, _) = crate::console::http(&http_addr, "GET", "/../../etc/passwd", &[], b"");
    t.check(
        "http: a path out of the console",
        code == 404 || code == 400,
        code,
    );

    // 64 browsers that keep their connections alive and idle take every slot of the console:
    // a 65th is served once the idle ones are closed (not never).
    let keep_alive = |addr: &str| -> Option<TcpStream> {
        let mut c = TcpStream::connect(addr).ok()?;
        c.set_read_timeout(Some(Duration::from_secs(10))).ok()?;
        c.write_all(format!("GET /api/status HTTP/1.1\r\nHost: {addr}\r\n\r\n").as_bytes())
            .ok()?;
        // The head, then the body by its length; the connection stays open.
        let mut got = Vec::new();
        let mut buf = [0u8; 4096];
        loop {
            let n = c.read(&mut buf).ok()?;
            if n == 0 {
                return None;
            }
            got.extend_from_slice(&buf[..n]);
            if let Some(i) = got.windows(4).position(|w| w == b"\r\n\r\n") {
                let head = String::from_utf8_lossy(&got[..i]).to_lowercase();
                let len: usize = head
                    .lines()
                    .find_map(|l| l.strip_prefix("content-length:"))?
                    .trim()
                    .parse()
                    .ok()?;
                if got.len() >= i + 4 + len {
                    return Some(c);
                }
            }
        }
    };
    let held: Vec<TcpStream> = (0..64).filter_map(|_| keep_alive(&http_addr)).collect();
    let started = Instant::now();
    let late = TcpStream::connect(&http_addr).and_then(|mut c| {
        c.set_read_timeout(Some(Duration::from_secs(60)))?;
        c.write_all(
            format!("GET /api/status HTTP/1.1\r\nHost: {http_addr}\r\nConnection: close\r\n\r\n")
                .as_bytes(),
        )?;
        let mut head = [0u8; 12];
        c.read_exact(&mut head)?;
        Ok(String::from_utf8_lossy(&head).into_owned())
    });
    t.check(
        "http: a 65th client past 64 idle keep-alive connections is served",
        held.len() == 64
            && late.as_deref().is_ok_and(|h| h.contains("200"))
            && started.elapsed() < Duration::from_secs(45),
        format!(
            "{} held; {late:?} after {:?}",
            held.len(),
            started.elapsed()
        ),
    );
    drop(held);

    // OSC: garbage, an address that is not compend's, an oversized string.
    let udp = UdpSocket::bind("127.0.0.1:0").unwrap();
    udp.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
    let osc = |packet: &[u8]| -> Option<Vec<u8>> {
        udp.send_to(packet, &osc_addr).ok()?;
        let mut buf = [0u8; 65_536];
        let n = udp.recv(&mut buf).ok()?;
        Some(buf[..n].to_vec())
    };
    // A refusal: `/compend/reply` with 0 (refused) first.
    let refusal = |reply: &Option<Vec<u8>>| {
        reply
            .as_deref()
            .and_then(|b| rosc::decoder::decode_udp(b).ok())
            .is_some_and(|(_, p)| match p {
                rosc::OscPacket::Message(m) => {
                    m.addr == "/compend/reply" && m.args.first() == Some(&rosc::OscType::Int(0))
                }
                rosc::OscPacket::Bundle(_) => false,
            })
    };
    let garbage = osc(b"\x00\x01not osc at all");
    t.check(
        "osc: not an OSC packet",
        refusal(&garbage),
        format!("{garbage:?}"),
    );
    let msg = |addr: &str, s: &str| {
        rosc::encoder::encode(&rosc::OscPacket::Message(rosc::OscMessage {
            addr: addr.into(),
            args: vec![rosc::OscType::String(s.into())],
        }))
        .unwrap()
    };
    for (name, packet) in [
        ("osc: an address not compend's", msg("/other/stop", "x")),
        (
            "osc: a 60 kB source",
            msg("/compend/play", &"z".repeat(60_000)),
        ),
    ] {
        let r = osc(&packet);
        t.check(
            name,
            refusal(&r),
            format!("{:?}", r.map(|b| String::from_utf8_lossy(&b).into_owned())),
        );
    }

    // Slow and silent clients: more idle connections than the service serves at once, a half
    // line that never ends, a subscriber that never reads; a new client is still answered.
    let idle: Vec<UnixStream> = (0..70)
        .filter_map(|_| UnixStream::connect(&svc.socket).ok())
        .collect();
    let mut half = UnixStream::connect(&svc.socket).unwrap();
    half.write_all(br#"{"cmd":"sta"#).unwrap();
    let mut deaf = UnixStream::connect(&svc.socket).unwrap();
    deaf.write_all(b"{\"cmd\":\"subscribe\"}\n").unwrap();
    let r = unix_line(&svc.socket, br#"{"cmd":"status"}"#);
    t.check(
        "unix: answered past 70 idle, a half line and a deaf subscriber",
        r.as_deref().is_some_and(|r| r.contains(r#""ok":true"#)),
        format!("{r:?}"),
    );
    drop((idle, half, deaf));

    // Hostile sources: each refused, and the picture plays on with the source it had.
    let pid = svc.status()["pid"].as_u64().unwrap() as u32;
    let fifo = dir.path().join("fifo");
    let c = std::ffi::CString::new(fifo.as_os_str().as_encoded_bytes()).unwrap();
    // SAFETY: a valid NUL-terminated path.
    assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
    let junk = dir.path().join("junk");
    std::fs::create_dir(&junk).unwrap();
    for i in 0..8 {
        // Sparse: 1000 MB each that take no disk, named as images.
        let f = std::fs::File::create(junk.join(format!("f{i}.png"))).unwrap();
        f.set_len(1_000_000_000).unwrap();
    }
    let sources = [
        ("source: v4l2:/dev/null", "v4l2:/dev/null".to_string()),
        (
            "source: a missing file",
            "/nonexistent/film.mp4".to_string(),
        ),
        (
            "source: /etc/passwd as an image",
            "image:/etc/passwd".to_string(),
        ),
        (
            "source: /dev/zero as an image",
            "image:/dev/zero".to_string(),
        ),
        (
            "source: a folder of 8 GB that are not images",
            format!("folder:{}", junk.display()),
        ),
        (
            "source: a folder as raw frames",
            format!("raw:{}?size=8x8", dir.path().display()),
        ),
        (
            "source: a pattern of 0x0",
            "pattern:bars?size=0x0".to_string(),
        ),
    ];
    for (name, s) in &sources {
        let started = Instant::now();
        let o = client(&["play", "--source", s], &svc.socket);
        let took = started.elapsed();
        let on = still_playing(&svc, &source);
        t.check(
            name,
            o.status.code() != Some(0) && on.is_ok() && took < Duration::from_secs(5),
            format!(
                "exit {:?} in {took:?}, {}; {}",
                o.status.code(),
                on.err().unwrap_or_default(),
                stderr(&o)
            ),
        );
    }
    // Files outside the media folders (`[playback] media`, here the test's folder), directly,
    // through a link that leads out, or as a file:// URI; a model outside `[paths] models`.
    let outside = tempfile::tempdir().unwrap();
    let png = outside.path().join("elsewhere.png");
    image::RgbImage::from_pixel(4, 4, image::Rgb([9, 9, 9]))
        .save(&png)
        .unwrap();
    let link = dir.path().join("link.png");
    std::os::unix::fs::symlink(&png, &link).unwrap();
    for (name, s) in [
        (
            "source: an image outside the media folders",
            format!("image:{}", png.display()),
        ),
        (
            "source: a link out of the media folders",
            format!("image:{}", link.display()),
        ),
        (
            "source: a file:// URI outside them",
            format!("uri:file://{}", png.display()),
        ),
        (
            "source: a film by file: outside them",
            format!("file:{}", png.display()),
        ),
    ] {
        let o = client(&["play", "--source", &s], &svc.socket);
        let on = still_playing(&svc, &source);
        t.check(
            name,
            o.status.code() == Some(1)
                && stderr(&o).contains("not in [playback] media")
                && on.is_ok(),
            format!("exit {:?}: {} {on:?}", o.status.code(), stderr(&o)),
        );
    }
    let r = unix_line(
        &svc.socket,
        format!(r#"{{"cmd":"model","path":"{}"}}"#, outside.path().display()).as_bytes(),
    );
    t.check(
        "model: a folder outside [paths] models",
        refused(&r) && r.as_deref().is_some_and(|r| r.contains("[paths] models")),
        format!("{r:?}"),
    );
    // A stream that never answers: while it is being opened the picture plays on (no source
    // is opened on the render thread), and it is refused within the opening's time.
    let silent = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let url = format!("uri:http://{}/film.mp4", silent.local_addr().unwrap());
    let socket = svc.socket.clone();
    let started = Instant::now();
    let asked = std::thread::spawn(move || client(&["play", "--source", &url], &socket));
    std::thread::sleep(Duration::from_secs(2));
    let during = still_playing(&svc, &source);
    let o = asked.join().unwrap();
    t.check(
        "source: a stream that never answers",
        o.status.code() != Some(0) && during.is_ok() && started.elapsed() < Duration::from_secs(30),
        format!(
            "exit {:?} after {:?}; while it opened: {during:?}; {}",
            o.status.code(),
            started.elapsed(),
            stderr(&o)
        ),
    );
    drop(silent);
    // A FIFO without a writer plays (it waits for one); ten such requests leave no thread
    // behind.
    let before = threads(pid);
    let mut taken = 0;
    for _ in 0..10 {
        let o = client(
            &[
                "play",
                "--source",
                &format!("raw:{}?size=200x150", fifo.display()),
            ],
            &svc.socket,
        );
        taken += usize::from(o.status.success());
    }
    t.check(
        "source: a FIFO without a writer is taken at once",
        taken == 10,
        format!("{taken} of 10 plays taken"),
    );
    std::thread::sleep(Duration::from_secs(2));
    let after = threads(pid);
    t.check(
        "source: ten plays of a FIFO without a writer leave no thread",
        after <= before + 1,
        format!("{before} → {after} threads"),
    );
    let o = client(&["play", "--source", &source], &svc.socket);
    t.check("the first source again", o.status.success(), stderr(&o));

    t.check(
        "the installed model is untouched",
        model_digest(&model).as_deref() == Some(&digest) && loads(&model),
        "the model changed",
    );
    let log = svc.log();
    let r = svc.ask(r#"{"cmd":"stop"}"#);
    assert_eq!(r["ok"], true, "{r}");
    assert_eq!(svc.wait_exit(30), Some(0));
    t.finish(&log);
}

/// A seeded schedule of moments, ms: `n` draws in `0..span` (xorshift, so the same seed gives
/// the same schedule on every machine).
fn schedule(seed: u64, n: usize, span: u64) -> Vec<u64> {
    let mut x = seed | 1;
    (0..n)
        .map(|_| {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            x % span
        })
        .collect()
}

#[test]
fn kill_9_at_seeded_moments_never_damages_the_installed_model() {
    if !gpu_or_skip() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let mut t = Tally::new("kill -9");
    // `compend calibrate` into a model that is installed already: killed at seeded moments of
    // a run (which resumes each time), the model is the old one or a new complete one.
    let data = dir.path().join("cal");
    let model = dir.path().join("model");
    let (d, m) = (data.to_str().unwrap(), model.to_str().unwrap());
    let args = |seed: &'static str| -> Vec<&str> {
        let rig = ["--rig", "virtual:dark-texture", "--seed", seed, "--out", m];
        crate::calibrate::calibrate_args(d, &rig)
    };
    let first = Instant::now();
    let o = compend(&args("5"));
    assert_code(&o, 0);
    let run_ms = first.elapsed().as_millis() as u64;
    let mut digests = vec![model_digest(&model).unwrap()];
    std::fs::remove_dir_all(&data).unwrap();
    for (k, at) in schedule(50, 6, run_ms).into_iter().enumerate() {
        let mut child = Command::new(env!("CARGO_BIN_EXE_compend"))
            .args(args("6"))
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap();
        std::thread::sleep(Duration::from_millis(at));
        let finished = child.try_wait().unwrap().is_some();
        let _ = child.kill();
        child.wait().unwrap();
        let d = model_digest(&model);
        if let Some(d) = &d
            && !digests.contains(d)
        {
            digests.push(d.clone());
        }
        t.check(
            &format!("calibrate killed at {at} ms (kill {})", k + 1),
            d.is_some() && loads(&model),
            format!(
                "model {:?} ({} digests seen){}",
                d,
                digests.len(),
                if finished { "; it had finished" } else { "" }
            ),
        );
    }
    // The last run resumes what the kills left and installs.
    let o = compend(&args("6"));
    t.check(
        "calibrate after the kills resumes and installs",
        o.status.code() == Some(0) && loads(&model),
        stderr(&o),
    );

    // `compend serve` killed at seeded moments of its recalibrations: after each restart the
    // model is the old one or a new complete one, and it plays.
    let config = write_config(dir.path(), "curved", 7, "", "");
    let mut svc = Service::start(&config);
    svc.wait_for("playback after the first calibration", 300, playing);
    let smodel = dir.path().join("state/model");
    let mut seen = vec![model_digest(&smodel).unwrap()];
    for (k, at) in schedule(51, 4, 6_000).into_iter().enumerate() {
        let r = svc.ask(r#"{"cmd":"recalibrate"}"#);
        assert_eq!(r["ok"], true, "{r}");
        std::thread::sleep(Duration::from_millis(at));
        let pid = svc.status()["pid"].as_i64().unwrap() as i32;
        // SAFETY: kill(2) on the service's own pid.
        unsafe { libc::kill(pid, libc::SIGKILL) };
        let _ = svc.wait_exit(20);
        let d = model_digest(&smodel);
        if let Some(d) = &d
            && !seen.contains(d)
        {
            seen.push(d.clone());
        }
        t.check(
            &format!("serve killed {at} ms into a recalibration (kill {})", k + 1),
            d.is_some() && loads(&smodel),
            format!("model {d:?}"),
        );
        svc = Service::start(&config);
        svc.wait_for("playback after the restart", 300, playing);
    }
    let log = svc.log();
    let r = svc.ask(r#"{"cmd":"stop"}"#);
    assert_eq!(r["ok"], true, "{r}");
    assert_eq!(svc.wait_exit(30), Some(0));
    t.finish(&log);
}

/// Mounts a tmpfs of `kib` KiB at `at`; false where this process may not (not root, or in a
/// container without the right).
fn mount_tmpfs(at: &Path, kib: u64) -> bool {
    std::fs::create_dir_all(at).unwrap();
    Command::new("mount")
        .args(["-t", "tmpfs", "-o", &format!("size={kib}k"), "tmpfs"])
        .arg(at)
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|s| s.success())
}

struct Unmount(PathBuf);

impl Drop for Unmount {
    fn drop(&mut self) {
        let _ = Command::new("umount").arg("-l").arg(&self.0).status();
    }
}

#[test]
fn a_full_disk_fails_a_recalibration_that_the_waiter_sees_and_loses_nothing() {
    if !gpu_or_skip() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let disk = dir.path().join("disk");
    if !mount_tmpfs(&disk, 64 * 1024) {
        // A matter of privileges, not of the GPU: skipped (CI runs as root, and mounts).
        eprintln!("skipping: cannot mount a tmpfs here (needs root and the right to mount)");
        return;
    }
    let _unmount = Unmount(disk.clone());
    // The state on the small disk; the configuration, the socket and the log beside it.
    let config = write_config(dir.path(), "curved", 8, "", "");
    let text = std::fs::read_to_string(&config).unwrap().replace(
        &format!("state = \"{}\"", dir.path().join("state").display()),
        &format!("state = \"{}\"", disk.join("state").display()),
    );
    std::fs::write(&config, text).unwrap();
    let mut svc = Service::start(&config);
    svc.wait_for("playback after the first calibration", 300, playing);
    let model = disk.join("state/model");
    let digest = model_digest(&model).unwrap();
    // Fill the disk.
    let mut filler = std::fs::File::create(disk.join("filler")).unwrap();
    let block = vec![7u8; 1 << 20];
    while filler.write_all(&block).is_ok() {}
    let _ = filler.sync_all();
    let started = Instant::now();
    let o = client(&["recalibrate", "--wait", "--timeout", "120"], &svc.socket);
    let mut t = Tally::new("full disk");
    t.check(
        "recalibrate --wait on a full disk ends with the failure",
        o.status.code() == Some(1) && started.elapsed() < Duration::from_secs(60),
        format!(
            "exit {:?} after {:?}: {}",
            o.status.code(),
            started.elapsed(),
            stderr(&o)
        ),
    );
    let s = svc.status();
    t.check(
        "status shows the failed calibration",
        s["last_calibration"]["installed"] == false,
        &s,
    );
    t.check(
        "the model is untouched",
        model_digest(&model).as_deref() == Some(&digest) && loads(&model),
        "the model changed",
    );
    t.check(
        "the picture plays on",
        svc.wait_for("playback after the failure", 60, playing)["state"] == "playing",
        "",
    );
    // And goes on with the disk full (monitoring, the log, the console's figures).
    std::thread::sleep(Duration::from_secs(10));
    t.check(
        "ten seconds more with the disk full",
        still_playing(&svc, svc.status()["source"].as_str().unwrap_or("")).is_ok(),
        svc.log(),
    );
    let log = svc.log();
    let r = svc.ask(r#"{"cmd":"stop"}"#);
    assert_eq!(r["ok"], true, "{r}");
    assert_eq!(svc.wait_exit(30), Some(0));
    t.finish(&log);
}

#[test]
fn an_unwritable_state_folder_exits_1_a_failed_reload_shows_in_status_and_an_unwritable_log_is_survived()
 {
    if !gpu_or_skip() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let mut t = Tally::new("permissions and reload");
    // As an unprivileged user, a state folder it cannot write: an operation's failure (1),
    // which systemd retries, not a configuration error (2).
    // SAFETY: geteuid has no preconditions.
    if unsafe { libc::geteuid() } == 0 {
        let state = dir.path().join("locked");
        std::fs::create_dir(&state).unwrap();
        let config = write_config(dir.path(), "curved", 9, "", "");
        let text = std::fs::read_to_string(&config).unwrap().replace(
            &format!("state = \"{}\"", dir.path().join("state").display()),
            &format!("state = \"{}\"", state.display()),
        );
        let cfg = dir.path().join("locked.toml");
        std::fs::write(&cfg, text).unwrap();
        // The temporary folder's parents must be passable for `nobody`.
        let mut p = dir.path().to_path_buf();
        loop {
            use std::os::unix::fs::PermissionsExt;
            let mode = std::fs::metadata(&p).unwrap().permissions().mode();
            std::fs::set_permissions(&p, std::fs::Permissions::from_mode(mode | 0o005)).unwrap();
            if !p.pop() || p.as_os_str() == "/" {
                break;
            }
        }
        let o = Command::new("setpriv")
            .args(["--reuid=65534", "--regid=65534", "--clear-groups"])
            .arg(env!("CARGO_BIN_EXE_compend"))
            .args(["serve", "--config", cfg.to_str().unwrap()])
            .stdin(Stdio::null())
            .output()
            .unwrap();
        t.check(
            "serve as nobody with a state folder it cannot write exits 1",
            o.status.code() == Some(1) && stderr(&o).contains("Permission denied"),
            format!("exit {:?}: {}", o.status.code(), stderr(&o)),
        );
    }
    // A SIGHUP with a configuration that does not parse: the running one stays, and `status`
    // says so. This service's log cannot be written at all (stderr is /dev/full): it calibrates
    // and plays all the same.
    let config = write_config(dir.path(), "curved", 9, "", "");
    let good = std::fs::read_to_string(&config).unwrap();
    let mut svc = Service::start_unlogged(&config);
    let s = svc.wait_for("playback after the first calibration", 300, playing);
    t.check(
        "a service whose log cannot be written calibrates and plays",
        s["calibrations"] == 1,
        &s,
    );
    std::fs::write(&config, format!("{good}\n[rig]\nkind = \"virtual\"\n")).unwrap();
    let pid = svc.status()["pid"].as_i64().unwrap() as i32;
    // SAFETY: kill(2) on the service's own pid.
    unsafe { libc::kill(pid, libc::SIGHUP) };
    let s = svc.wait_for("the failed reload in status", 30, |s| {
        s["last_error"]
            .as_str()
            .is_some_and(|e| e.contains("SIGHUP"))
    });
    t.check(
        "a failed reload shows in status, the service plays on",
        s["state"] == "playing",
        &s,
    );
    std::fs::write(&config, good).unwrap();
    let log = svc.log();
    let r = svc.ask(r#"{"cmd":"stop"}"#);
    assert_eq!(r["ok"], true, "{r}");
    assert_eq!(svc.wait_exit(30), Some(0));
    t.finish(&log);
}

#[test]
fn config_check_refuses_what_serve_would_and_two_calibrations_do_not_share_a_folder() {
    let dir = tempfile::tempdir().unwrap();
    let mut t = Tally::new("config check and locks");
    let base = write_config(dir.path(), "curved", 10, "", "");
    let good = std::fs::read_to_string(&base).unwrap();
    let state = dir.path().join("state");
    let socket = dir.path().join("compend.sock");
    let short = dir.path().join("short-token");
    std::fs::write(&short, "abcde\n").unwrap();
    let file = dir.path().join("a-file");
    std::fs::write(&file, "keep me").unwrap();
    let link = dir.path().join("a-link");
    std::os::unix::fs::symlink(&file, &link).unwrap();
    let swap = |from: &str, to: &str| good.replace(from, to);
    let state_line = format!("state = \"{}\"", state.display());
    let socket_line = format!("path = \"{}\"", socket.display());
    let cases = [
        (
            "one [[projector]] section for a set of two",
            swap("scene = \"curved\"", "scene = \"tiled\"")
                .replace("[paths]\n", "[[projector]]\n\n[paths]\n"),
            "1 section(s), and scene \"tiled\" has 2 projector(s)",
        ),
        (
            "socket path is a regular file",
            swap(&socket_line, &format!("path = \"{}\"", file.display())),
            "a file that is not a socket",
        ),
        (
            "socket path is a symbolic link",
            swap(&socket_line, &format!("path = \"{}\"", link.display())),
            "a symbolic link",
        ),
        (
            "socket path is /dev/null",
            swap(&socket_line, "path = \"/dev/null\""),
            "not a socket",
        ),
        (
            "a 5-character token",
            swap(
                "[socket]\n",
                &format!(
                    "[socket]\ntcp = \"127.0.0.1:0\"\ntcp_token_file = \"{}\"\n",
                    short.display()
                ),
            ),
            "at least",
        ),
        (
            "state at /",
            swap(&state_line, "state = \"/\""),
            "a folder of the system",
        ),
        (
            "data at /etc",
            swap(&state_line, &format!("{state_line}\ndata = \"/etc\"")),
            "a folder of the system",
        ),
        (
            "data inside the model folder",
            swap(
                &state_line,
                &format!(
                    "{state_line}\ndata = \"{}\"",
                    state.join("model/runs").display()
                ),
            ),
            "inside [paths] model",
        ),
    ];
    for (name, text, says) in &cases {
        let cfg = dir.path().join("case.toml");
        std::fs::write(&cfg, text).unwrap();
        let o = compend(&["config", "check", cfg.to_str().unwrap()]);
        t.check(
            &format!("config check: {name}"),
            o.status.code() == Some(2) && stderr(&o).contains(says),
            format!("exit {:?}: {}", o.status.code(), stderr(&o)),
        );
    }
    t.check(
        "nothing named by a bad configuration was touched",
        std::fs::read_to_string(&file).unwrap() == "keep me" && !state.exists(),
        "a file changed",
    );

    // Two calibrations into one data folder: the second is refused while the first runs, and
    // the first installs.
    let data = dir.path().join("cal");
    let args =
        crate::calibrate::calibrate_args(data.to_str().unwrap(), &["--rig", "virtual:curved"]);
    let mut first = Command::new(env!("CARGO_BIN_EXE_compend"))
        .args(&args)
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // Once it captures.
    let manifest = data.join("capture/calibration.json");
    let start = Instant::now();
    while !manifest.is_file() {
        assert!(start.elapsed() < Duration::from_secs(60), "no captures");
        std::thread::sleep(Duration::from_millis(20));
    }
    let second = compend(&args);
    t.check(
        "a second calibrate on the same --data is refused",
        second.status.code() == Some(2) && stderr(&second).contains("holds this data folder"),
        format!("exit {:?}: {}", second.status.code(), stderr(&second)),
    );
    let status = first.wait().unwrap();
    let mut err = String::new();
    first
        .stderr
        .take()
        .unwrap()
        .read_to_string(&mut err)
        .unwrap();
    t.check(
        "the first calibrate installs",
        status.success() && loads(&data.join("model")),
        err,
    );
    t.finish("");
}
