//! `compend bench-serve`: the service's targets, measured by running the real service
//! (`compend serve`, this binary) on the virtual rig and driving it through its control socket
//! as a client would. Every figure sits next to a baseline from the same run:
//! - status round trips (connect, request, reply) while the service calibrates and trains,
//!   against the same round trips while it plays;
//! - a flood of malformed requests (garbage, unknown commands and fields, oversized lines,
//!   invalid UTF-8) over several connections at once; then whether it still answers and plays;
//! - frames dropped while a model is swapped in, against an equal span of playback without one;
//! - how long monitoring takes to report drift after the projector is bumped, in monitoring
//!   periods;
//! - the console under load (`--browsers` pages: each an event stream, the status once a second
//!   and the camera image four times a second; and an OSC controller sending ten messages a
//!   second) against equal spans without it, in alternating rounds; and the console's status
//!   round trips over HTTP while training, against the same while playing;
//! - how long SIGTERM takes to stop it, and its exit code.
//!
//! Writes bench-serve.json and bench-serve.md in `--out`, with the services' logs.

use std::io::{BufRead, BufReader, Write};
use std::os::unix::net::UnixStream;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use compend::raster::ImageSize;
use compend::service::protocol::{Frames, Request, State, Status};
use compend::service::socket;
use serde::Serialize;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// Folder for bench-serve.json, bench-serve.md, the configurations and the service logs.
    #[arg(long)]
    pub out: PathBuf,
    /// Built-in scene of the first run (calibration, flood, swaps).
    #[arg(long, default_value = "curved")]
    pub scene: String,
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Virtual camera resolution.
    #[arg(long, value_parser = super::sim::parse_size, default_value = "640x480")]
    pub camera: ImageSize,
    /// Projector resolution (also the played pattern's size).
    #[arg(long, value_parser = super::sim::parse_size, default_value = "800x600")]
    pub projector: ImageSize,
    /// Display refresh rate and source frame rate, Hz.
    #[arg(long, default_value_t = 30.0)]
    pub fps: f64,
    /// Sampling images captured for the fit.
    #[arg(long, default_value_t = 48)]
    pub ntrain: usize,
    /// Malformed requests in the flood.
    #[arg(long, default_value_t = 10_000)]
    pub malformed: usize,
    /// Connections the flood is spread over, at once.
    #[arg(long, default_value_t = 8)]
    pub connections: usize,
    /// Model swaps, each next to an equal span of playback without one.
    #[arg(long, default_value_t = 3)]
    pub swaps: usize,
    /// Seconds of playback watched per swap (and per baseline span).
    #[arg(long, default_value_t = 3.0)]
    pub window: f64,
    /// Pages open on the console in its load rounds.
    #[arg(long, default_value_t = 5)]
    pub browsers: usize,
    /// Rounds of playback with the console's load, each next to an equal span without.
    #[arg(long, default_value_t = 3)]
    pub console_rounds: usize,
    /// Monitoring period of the drift run, s.
    #[arg(long, default_value_t = 2.0)]
    pub period: f64,
    /// The drift run's bump of the projector, pixels of an 800-pixel-wide projector (the
    /// built-in drift scene moves 1.5).
    #[arg(long, default_value_t = 24.0)]
    pub bump: f64,
    /// The drift run's policy (`[monitoring] on_drift`): `report` measures detection only;
    /// `refit` and `recalibrate` also how long until the new model plays and how it scores.
    #[arg(long, default_value = "report", value_parser = ["report", "refit", "recalibrate"])]
    pub on_drift: String,
}

/// Quantiles of a set of durations, ms.
#[derive(Serialize, Debug, Default)]
struct Spread {
    n: usize,
    p50_ms: f64,
    p99_ms: f64,
    max_ms: f64,
}

impl Spread {
    fn of(samples: &[f64]) -> Self {
        if samples.is_empty() {
            return Self::default();
        }
        let mut v = samples.to_vec();
        v.sort_by(f64::total_cmp);
        let at = |q: f64| v[((v.len() - 1) as f64 * q).round() as usize];
        Self {
            n: v.len(),
            p50_ms: at(0.5),
            p99_ms: at(0.99),
            max_ms: v[v.len() - 1],
        }
    }
}

#[derive(Serialize, Debug)]
struct StatusLatency {
    /// While calibrating, training or verifying.
    busy: Spread,
    /// While training alone.
    training: Spread,
    /// While playing: the baseline.
    playing: Spread,
    /// `GET /api/status` on the console while training, and while playing.
    http_training: Spread,
    http_playing: Spread,
}

#[derive(Serialize, Debug)]
struct ConsoleRound {
    with_load: Span,
    without: Span,
    /// Requests the pages made (status and camera images), and OSC replies heard.
    page_requests: u64,
    camera_images: u64,
    events_read: u64,
    osc_sent: u64,
    osc_replies: u64,
}

#[derive(Serialize, Debug)]
struct Flood {
    requests: usize,
    connections: usize,
    seconds: f64,
    /// Requests answered with an error, as they all should be.
    error_replies: usize,
    /// Status answered afterwards, still playing, frames still shown.
    still_playing: bool,
    dropped_during: u64,
    shown_during: u64,
}

#[derive(Serialize, Debug)]
struct Span {
    shown: u64,
    dropped_source: u64,
    dropped_pipeline: u64,
}

#[derive(Serialize, Debug)]
struct Swap {
    reply_ms: f64,
    reply: String,
    with_swap: Span,
    without: Span,
}

#[derive(Serialize, Debug)]
struct Drift {
    period_s: f64,
    bump_px: f64,
    baseline_psnr: Option<f64>,
    psnr_after: Option<f64>,
    /// Seconds from the bump to the first status that reports drift; `None`: not within the
    /// time allowed (ten periods).
    detected_after_s: Option<f64>,
    detected_after_periods: Option<f64>,
    on_drift: String,
    /// `refit`/`recalibrate`: seconds from the detection until the new model plays.
    recovered_after_s: Option<f64>,
    /// The new model's first monitoring score, dB.
    psnr_recovered: Option<f64>,
    /// Its verification PSNR and sampling images (from its calibration record).
    verified_psnr: Option<f64>,
    sampling_images: Option<usize>,
}

#[derive(Serialize, Debug)]
struct Stop {
    signal: &'static str,
    seconds: f64,
    exit_code: Option<i32>,
}

#[derive(Serialize, Debug)]
struct Report {
    scene: String,
    seed: u64,
    camera: String,
    projector: String,
    fps: f64,
    calibration_s: f64,
    status: StatusLatency,
    flood: Flood,
    swaps: Vec<Swap>,
    console: Vec<ConsoleRound>,
    drift: Drift,
    stops: Vec<Stop>,
}

/// A service started for the bench; killed if the bench ends without stopping it.
struct Service {
    child: Option<Child>,
    socket: PathBuf,
    log: PathBuf,
}

impl Service {
    fn start(config: &Path, log: &Path) -> Result<Self> {
        let exe = std::env::current_exe().context("cannot find this program to start it")?;
        let log_file = std::fs::File::create(log)
            .with_context(|| format!("{}: cannot create the service log", log.display()))?;
        let child = Command::new(exe)
            .args(["serve", "--config"])
            .arg(config)
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(log_file)
            .spawn()
            .context("cannot start compend serve")?;
        let text = std::fs::read_to_string(config)?;
        let socket = compend::config::Config::parse(&text, config)?.socket.path;
        Ok(Self {
            child: Some(child),
            socket,
            log: log.to_path_buf(),
        })
    }

    /// An error when the service has exited: its code and the end of its log.
    fn exited(&mut self) -> Result<()> {
        if let Some(child) = self.child.as_mut()
            && let Some(code) = child.try_wait()?
        {
            let log = std::fs::read_to_string(&self.log).unwrap_or_default();
            let tail: Vec<&str> = log.lines().rev().take(8).collect();
            let tail: Vec<&str> = tail.into_iter().rev().collect();
            bail!(
                "the service exited ({code}); the end of {}:\n{}",
                self.log.display(),
                tail.join("\n")
            );
        }
        Ok(())
    }

    /// A status round trip: its time, ms, and the status (`None` while the socket is not up).
    fn status(&mut self) -> Result<Option<(f64, Status)>> {
        let mut attempt = 0;
        loop {
            self.exited()?;
            let t = Instant::now();
            match socket::request(&self.socket, &Request::Status) {
                Ok(reply) => {
                    return Ok(reply.status.map(|s| (t.elapsed().as_secs_f64() * 1e3, *s)));
                }
                Err(_) if !self.socket.exists() => return Ok(None),
                Err(e) => {
                    // The service may have ended between the check and the request; a live one
                    // that refused gets two more tries, 50 ms apart, before the bench gives up.
                    self.exited()?;
                    attempt += 1;
                    if attempt >= 3 {
                        return Err(e.into());
                    }
                    std::thread::sleep(Duration::from_millis(50));
                }
            }
        }
    }

    fn frames(&mut self) -> Result<Frames> {
        match self.status()? {
            Some((_, s)) => Ok(s.frames),
            None => bail!("the service's socket is gone"),
        }
    }

    /// Sends `signal` and waits for the exit.
    fn stop(&mut self, signal: &'static str) -> Result<Stop> {
        let Some(mut child) = self.child.take() else {
            bail!("the service is not running");
        };
        use nix::sys::signal::Signal;
        let sig = if signal == "SIGTERM" {
            Signal::SIGTERM
        } else {
            Signal::SIGINT
        };
        let t = Instant::now();
        // A child that has already exited is found by the wait below.
        let _ = nix::sys::signal::kill(nix::unistd::Pid::from_raw(child.id() as i32), sig);
        let status = loop {
            if let Some(s) = child.try_wait()? {
                break s;
            }
            if t.elapsed() > Duration::from_secs(60) {
                let _ = child.kill();
                bail!("the service did not stop within 60 s of {signal}");
            }
            std::thread::sleep(Duration::from_millis(10));
        };
        Ok(Stop {
            signal,
            seconds: t.elapsed().as_secs_f64(),
            exit_code: status.code(),
        })
    }
}

impl Drop for Service {
    fn drop(&mut self) {
        if let Some(mut c) = self.child.take() {
            let _ = c.kill();
            let _ = c.wait();
        }
    }
}

fn write_config(args: &Args, dir: &Path, scene: &str, extra: (&str, &str)) -> Result<PathBuf> {
    let (rig, monitoring) = extra;
    let text = format!(
        "[rig]\nkind = \"virtual\"\nscene = {scene:?}\nseed = {seed}\ncamera_size = \"{cam}\"\n\
         projector = \"{prj}\"\nfps = {fps}\n{rig}\n\n[paths]\nstate = {state:?}\n\n\
         [calibration]\nntrain = {ntrain}\n\n[playback]\nsource = \"pattern:moving?size={prj}&fps={fps}\"\n\n\
         [monitoring]\n{monitoring}\n\n[socket]\npath = {socket:?}\n\n[http]\nlisten = \"127.0.0.1:0\"\n\n[osc]\nlisten = \"127.0.0.1:0\"\n\n[log]\nstats_period_s = 10.0\n",
        seed = args.seed,
        cam = args.camera,
        prj = args.projector,
        fps = args.fps,
        state = dir.join("state").display().to_string(),
        ntrain = args.ntrain,
        socket = dir.join("compend.sock").display().to_string(),
    );
    let path = dir.join("compend.toml");
    std::fs::create_dir_all(dir).with_context(|| format!("{}: cannot create", dir.display()))?;
    compend::files::write_atomically(&path, text.as_bytes())?;
    Ok(path)
}

pub fn run(args: Args) -> Result<()> {
    compend::files::check_out_folder(&args.out)?;
    if args.out.exists() && std::fs::read_dir(&args.out)?.next().is_some() {
        return Err(compend::Error::Input(format!(
            "--out {}: not empty; bench-serve writes a service state there, so it takes an \
             empty or new folder",
            args.out.display()
        ))
        .into());
    }
    let first = args.out.join("run");
    let config = write_config(&args, &first, &args.scene, ("", "period_s = 1.0"))?;
    let mut svc = Service::start(&config, &args.out.join("serve-run.log"))?;
    eprintln!(
        "bench-serve: calibrating {} (status polled every 10 ms)",
        args.scene
    );
    let (status, calibration_s) = status_until_playing(&mut svc)?;
    eprintln!(
        "bench-serve: status p99 {:.2} ms training, {:.2} ms playing; flooding",
        status.training.p99_ms, status.playing.p99_ms
    );
    let flood = flood(&mut svc, &args)?;
    eprintln!(
        "bench-serve: {} error replies; swapping models",
        flood.error_replies
    );
    let model = first.join("state/model");
    let mut swaps = Vec::new();
    for _ in 0..args.swaps {
        swaps.push(swap(&mut svc, &model, args.window)?);
    }
    eprintln!(
        "bench-serve: the console with {} pages and an OSC controller",
        args.browsers
    );
    let mut console = Vec::new();
    for _ in 0..args.console_rounds {
        console.push(console_round(&mut svc, args.browsers, args.window)?);
    }
    let mut stops = vec![svc.stop("SIGTERM")?];

    let second = args.out.join("drift");
    let scene_file = bumped_scene(&args, &second)?;
    let rig = "drift_after_s = 6.0";
    let monitoring = format!(
        "period_s = {}\non_drift = \"{}\"",
        args.period, args.on_drift
    );
    let config = write_config(&args, &second, &scene_file, (rig, &monitoring))?;
    let mut svc = Service::start(&config, &args.out.join("serve-drift.log"))?;
    eprintln!("bench-serve: the drift run (bump {} px)", args.bump);
    let drift = drift(&mut svc, &args, 6.0, &second.join("state/model"))?;
    stops.push(svc.stop("SIGINT")?);

    let report = Report {
        scene: args.scene.clone(),
        seed: args.seed,
        camera: args.camera.to_string(),
        projector: args.projector.to_string(),
        fps: args.fps,
        calibration_s,
        status,
        flood,
        swaps,
        console,
        drift,
        stops,
    };
    compend::files::write_atomically(
        &args.out.join("bench-serve.json"),
        serde_json::to_string_pretty(&report)?.as_bytes(),
    )?;
    let md = markdown(&report);
    compend::files::write_atomically(&args.out.join("bench-serve.md"), md.as_bytes())?;
    print!("{md}");
    Ok(())
}

/// Polls the status every 10 ms from the start until the service has played a second; the
/// round trips by state, and the seconds until it played.
fn status_until_playing(svc: &mut Service) -> Result<(StatusLatency, f64)> {
    let start = Instant::now();
    let (mut busy, mut training, mut playing) = (Vec::new(), Vec::new(), Vec::new());
    let (mut http_training, mut http_playing) = (Vec::new(), Vec::new());
    let mut played_at = None;
    while start.elapsed() < Duration::from_secs(1800) {
        std::thread::sleep(Duration::from_millis(10));
        let Some((ms, s)) = svc.status()? else {
            continue;
        };
        // The console's status, timed the same way right after.
        let web = match &s.http {
            Some(addr) => {
                let t = Instant::now();
                http_get(addr, "/api/status")
                    .ok()
                    .filter(|(code, _)| *code == 200)
                    .map(|_| t.elapsed().as_secs_f64() * 1e3)
            }
            None => None,
        };
        match (s.state, web) {
            (State::Training, Some(w)) => http_training.push(w),
            (State::Playing, Some(w)) => http_playing.push(w),
            _ => {}
        }
        match s.state {
            State::Training => {
                training.push(ms);
                busy.push(ms);
            }
            State::Calibrating | State::Verifying => busy.push(ms),
            State::Playing => {
                played_at.get_or_insert(start.elapsed().as_secs_f64());
                playing.push(ms);
            }
            _ => {}
        }
        if playing.len() >= 300 {
            let status = StatusLatency {
                busy: Spread::of(&busy),
                training: Spread::of(&training),
                playing: Spread::of(&playing),
                http_training: Spread::of(&http_training),
                http_playing: Spread::of(&http_playing),
            };
            return Ok((status, played_at.unwrap_or(0.0)));
        }
    }
    bail!("the service did not calibrate and play within 30 minutes")
}

/// The malformed lines of the flood, in turn; every 100th is longer than the protocol takes.
fn malformed(i: usize) -> Vec<u8> {
    if i % 100 == 99 {
        return vec![b'{'; 70 * 1024];
    }
    let lines: [&[u8]; 8] = [
        b"hello",
        b"{\"cmd\":\"reboot\"}",
        b"{\"cmd\":\"status\",\"x\":1}",
        b"\xff\xfe{\"cmd\"",
        b"[1,2,3]",
        b"{\"cmd\":\"model\"}",
        b"",
        b"{\"cmd\":",
    ];
    lines[i % lines.len()].to_vec()
}

/// Sends `args.malformed` malformed requests over `args.connections` connections at once, each
/// waiting for its reply; then checks the service still answers and plays.
fn flood(svc: &mut Service, args: &Args) -> Result<Flood> {
    let before = svc.frames()?;
    let t = Instant::now();
    let per = args.malformed.div_ceil(args.connections.max(1));
    let workers: Vec<_> = (0..args.connections.max(1))
        .map(|c| {
            let socket = svc.socket.clone();
            let n = per.min(args.malformed.saturating_sub(c * per));
            std::thread::spawn(move || -> Result<usize> {
                let mut stream = UnixStream::connect(&socket)?;
                stream.set_read_timeout(Some(Duration::from_secs(30)))?;
                let mut reader = BufReader::new(stream.try_clone()?);
                let mut errors = 0;
                let mut line = String::new();
                for i in 0..n {
                    let mut req = malformed(c * per + i);
                    req.push(b'\n');
                    stream.write_all(&req)?;
                    line.clear();
                    reader.read_line(&mut line)?;
                    let reply: serde_json::Value = serde_json::from_str(line.trim())
                        .with_context(|| format!("unreadable reply {line:?}"))?;
                    if reply["ok"] == false {
                        errors += 1;
                    }
                }
                Ok(errors)
            })
        })
        .collect();
    let mut error_replies = 0;
    for w in workers {
        error_replies += w
            .join()
            .map_err(|_| anyhow::anyhow!("a flood connection panicked"))??;
    }
    let seconds = t.elapsed().as_secs_f64();
    let after = svc.frames()?;
    std::thread::sleep(Duration::from_millis(500));
    let later = svc.status()?;
    let still_playing = later
        .as_ref()
        .is_some_and(|(_, s)| s.state == State::Playing && s.frames.shown > after.shown);
    Ok(Flood {
        requests: args.malformed,
        connections: args.connections,
        seconds,
        error_replies,
        still_playing,
        dropped_during: drops(&after) - drops(&before),
        shown_during: after.shown.saturating_sub(before.shown),
    })
}

fn drops(f: &Frames) -> u64 {
    f.dropped_source + f.dropped_pipeline
}

/// Frame counts over `seconds` from `before`.
fn span(svc: &mut Service, before: &Frames, until: Instant) -> Result<Span> {
    if let Some(rest) = until.checked_duration_since(Instant::now()) {
        std::thread::sleep(rest);
    }
    let after = svc.frames()?;
    Ok(Span {
        shown: after.shown.saturating_sub(before.shown),
        dropped_source: after.dropped_source.saturating_sub(before.dropped_source),
        dropped_pipeline: after
            .dropped_pipeline
            .saturating_sub(before.dropped_pipeline),
    })
}

/// One span of playback without a swap, then one with the model at `model` swapped in at its
/// start.
fn swap(svc: &mut Service, model: &Path, window: f64) -> Result<Swap> {
    let w = Duration::from_secs_f64(window);
    let before = svc.frames()?;
    let without = span(svc, &before, Instant::now() + w)?;
    let before = svc.frames()?;
    let t = Instant::now();
    let reply = socket::request(
        &svc.socket,
        &Request::Model {
            path: model.to_path_buf(),
        },
    )?;
    let reply_ms = t.elapsed().as_secs_f64() * 1e3;
    let with_swap = span(svc, &before, t + w)?;
    Ok(Swap {
        reply_ms,
        reply: reply
            .message
            .or(reply.error)
            .unwrap_or_else(|| "no message".into()),
        with_swap,
        without,
    })
}

/// One `GET path` on the console at `addr` (`Connection: close`): its status code and body.
fn http_get(addr: &str, path: &str) -> Result<(u16, Vec<u8>)> {
    use std::io::Read;
    let mut s = std::net::TcpStream::connect(addr)?;
    s.set_read_timeout(Some(Duration::from_secs(30)))?;
    write!(
        s,
        "GET {path} HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\n\r\n"
    )?;
    let mut all = Vec::new();
    s.read_to_end(&mut all)?;
    let head_end = all
        .windows(4)
        .position(|w| w == b"\r\n\r\n")
        .context("no HTTP head in the console's reply")?;
    let code = String::from_utf8_lossy(&all[..head_end])
        .split_whitespace()
        .nth(1)
        .and_then(|c| c.parse().ok())
        .context("no status code in the console's reply")?;
    Ok((code, all[head_end + 4..].to_vec()))
}

/// What the console's load did: counts kept by its threads.
#[derive(Default)]
struct LoadCounts {
    page_requests: AtomicU64,
    camera_images: AtomicU64,
    events_read: AtomicU64,
    osc_sent: AtomicU64,
    osc_replies: AtomicU64,
}

/// Runs the console's load until `stop`: `browsers` pages (an event stream each, the status
/// once a second, the camera image four times a second) and an OSC controller asking for the
/// state ten times a second.
fn console_load(
    http: String,
    osc: String,
    browsers: usize,
    stop: Arc<AtomicBool>,
    counts: Arc<LoadCounts>,
) -> Vec<std::thread::JoinHandle<()>> {
    let mut threads = Vec::new();
    for _ in 0..browsers {
        // The page's event stream, read as it comes.
        let (addr, stop2, c) = (http.clone(), stop.clone(), counts.clone());
        threads.push(std::thread::spawn(move || {
            let Ok(mut s) = std::net::TcpStream::connect(&addr) else {
                return;
            };
            let _ = s.set_read_timeout(Some(Duration::from_millis(200)));
            let _ = write!(s, "GET /api/events HTTP/1.1\r\nHost: {addr}\r\n\r\n");
            let mut r = BufReader::new(s);
            let mut line = String::new();
            while !stop2.load(Ordering::Relaxed) {
                line.clear();
                if r.read_line(&mut line).is_ok() && line.starts_with("data:") {
                    c.events_read.fetch_add(1, Ordering::Relaxed);
                }
            }
        }));
        // Its polling.
        let (addr, stop2, c) = (http.clone(), stop.clone(), counts.clone());
        threads.push(std::thread::spawn(move || {
            let mut tick = 0u64;
            while !stop2.load(Ordering::Relaxed) {
                if http_get(&addr, "/api/camera.jpg").is_ok_and(|(code, _)| code == 200) {
                    c.camera_images.fetch_add(1, Ordering::Relaxed);
                }
                if tick.is_multiple_of(4) && http_get(&addr, "/api/status").is_ok() {
                    c.page_requests.fetch_add(1, Ordering::Relaxed);
                }
                tick += 1;
                std::thread::sleep(Duration::from_millis(250));
            }
        }));
    }
    threads.push(std::thread::spawn(move || {
        let Ok(sock) = std::net::UdpSocket::bind("127.0.0.1:0") else {
            return;
        };
        let packet = rosc::encoder::encode(&rosc::OscPacket::Message(rosc::OscMessage {
            addr: "/compend/status".into(),
            args: Vec::new(),
        }))
        .unwrap_or_default();
        let mut buf = [0u8; 2048];
        let start = Instant::now();
        let mut sent = 0u32;
        while !stop.load(Ordering::Relaxed) {
            if sock.send_to(&packet, &osc).is_ok() {
                counts.osc_sent.fetch_add(1, Ordering::Relaxed);
            }
            sent += 1;
            // Ten a second: the replies are read until the next one is due.
            let due = start + Duration::from_millis(100) * sent;
            while let Some(left) = due.checked_duration_since(Instant::now()) {
                let _ = sock.set_read_timeout(Some(left.max(Duration::from_millis(1))));
                if sock.recv_from(&mut buf).is_ok() {
                    counts.osc_replies.fetch_add(1, Ordering::Relaxed);
                } else {
                    break;
                }
            }
            if let Some(left) = due.checked_duration_since(Instant::now()) {
                std::thread::sleep(left);
            }
        }
    }));
    threads
}

/// One span of playback without the console's load, then one with it.
fn console_round(svc: &mut Service, browsers: usize, window: f64) -> Result<ConsoleRound> {
    let Some((_, s)) = svc.status()? else {
        bail!("the service's socket is gone");
    };
    let (Some(http), Some(osc)) = (s.http, s.osc) else {
        bail!("the service serves no console or no OSC port; the bench's configuration sets both");
    };
    let w = Duration::from_secs_f64(window);
    let before = svc.frames()?;
    let without = span(svc, &before, Instant::now() + w)?;
    let stop = Arc::new(AtomicBool::new(false));
    let counts = Arc::new(LoadCounts::default());
    let threads = console_load(http, osc, browsers, stop.clone(), counts.clone());
    // The pages open before the span counts.
    std::thread::sleep(Duration::from_millis(500));
    let before = svc.frames()?;
    let with_load = span(svc, &before, Instant::now() + w)?;
    stop.store(true, Ordering::Relaxed);
    for t in threads {
        let _ = t.join();
    }
    let n = |a: &AtomicU64| a.load(Ordering::Relaxed);
    Ok(ConsoleRound {
        with_load,
        without,
        page_requests: n(&counts.page_requests),
        camera_images: n(&counts.camera_images),
        events_read: n(&counts.events_read),
        osc_sent: n(&counts.osc_sent),
        osc_replies: n(&counts.osc_replies),
    })
}

/// The built-in drift scene with the bump of `--bump`, as a scene file in `dir`.
fn bumped_scene(args: &Args, dir: &Path) -> Result<String> {
    let mut scene = compend::rig::scene::load("drift")?;
    let k = args.bump / 1.5;
    if let Some(d) = &mut scene.drift {
        d.shift_px = [d.shift_px[0] * k, d.shift_px[1] * k];
    }
    std::fs::create_dir_all(dir)?;
    let path = dir.join("bumped-drift.json");
    compend::files::write_atomically(&path, serde_json::to_string_pretty(&scene)?.as_bytes())?;
    Ok(path.display().to_string())
}

/// Waits for playback, then for the first status that reports drift after the bump
/// `bump_after` seconds into the playback; with a policy that acts on drift, then for the new
/// model (installed at `model`) to play and be scored.
fn drift(svc: &mut Service, args: &Args, bump_after: f64, model: &Path) -> Result<Drift> {
    let start = Instant::now();
    let played = loop {
        if start.elapsed() > Duration::from_secs(1800) {
            bail!("the drift run did not play within 30 minutes");
        }
        std::thread::sleep(Duration::from_millis(10));
        if let Some((_, s)) = svc.status()?
            && s.state == State::Playing
        {
            break Instant::now();
        }
    };
    let bump = played + Duration::from_secs_f64(bump_after);
    let mut baseline = None;
    let mut detected = None;
    let mut psnr_after = None;
    let mut calibrations = 0;
    while Instant::now() < bump + Duration::from_secs_f64(10.0 * args.period) {
        std::thread::sleep(Duration::from_millis(20));
        let Some((_, s)) = svc.status()? else {
            continue;
        };
        baseline = baseline.or(s.monitoring.baseline_psnr);
        calibrations = s.calibrations;
        if s.monitoring.drifts > 0 {
            detected = Some(Instant::now());
            psnr_after = s.monitoring.psnr;
            break;
        }
    }
    let (mut recovered, mut psnr_recovered) = (None, None);
    if let Some(at) = detected
        && args.on_drift != "report"
    {
        // The new model plays, then its first monitoring check.
        while at.elapsed() < Duration::from_secs(1800) {
            std::thread::sleep(Duration::from_millis(20));
            let Some((_, s)) = svc.status()? else {
                continue;
            };
            if s.calibrations > calibrations && s.state == State::Playing {
                recovered.get_or_insert(at.elapsed().as_secs_f64());
                if s.monitoring.checks > 0 && s.monitoring.psnr.is_some() {
                    psnr_recovered = s.monitoring.psnr;
                    break;
                }
            }
        }
    }
    let record = recovered
        .and_then(|_| compend::model::store::load(model).ok())
        .and_then(|(meta, _)| meta.calibration.map(|c| (c, meta.training.ntrain)));
    let detected = detected.map(|at| at.saturating_duration_since(bump).as_secs_f64());
    Ok(Drift {
        period_s: args.period,
        bump_px: args.bump,
        baseline_psnr: baseline,
        psnr_after,
        detected_after_s: detected,
        detected_after_periods: detected.map(|d| d / args.period),
        on_drift: args.on_drift.clone(),
        recovered_after_s: recovered,
        psnr_recovered,
        verified_psnr: record.as_ref().map(|(c, _)| c.verification.psnr),
        sampling_images: record.map(|(_, n)| n),
    })
}

fn markdown(r: &Report) -> String {
    let s = &r.status;
    let mut md = format!(
        "# compend bench-serve\n\nScene {} (seed {}), camera {}, projector {}, {} Hz; the first \
         calibration played after {:.1} s.\n\n## Status round trips (connect, request, reply)\n\n\
         | while | n | p50 ms | p99 ms | max ms |\n|---|---|---|---|---|\n",
        r.scene, r.seed, r.camera, r.projector, r.fps, r.calibration_s
    );
    for (name, x) in [
        ("training", &s.training),
        ("calibrating/training/verifying", &s.busy),
        ("playing (baseline)", &s.playing),
        ("training, the console's GET /api/status", &s.http_training),
        ("playing, the console's GET /api/status", &s.http_playing),
    ] {
        md += &format!(
            "| {name} | {} | {:.2} | {:.2} | {:.2} |\n",
            x.n, x.p50_ms, x.p99_ms, x.max_ms
        );
    }
    let f = &r.flood;
    md += &format!(
        "\n## Malformed requests\n\n{} requests over {} connections in {:.2} s; {} error \
         replies; still playing afterwards: {}; frames shown during the flood {}, dropped {}.\n",
        f.requests,
        f.connections,
        f.seconds,
        f.error_replies,
        f.still_playing,
        f.shown_during,
        f.dropped_during
    );
    md += "\n## Model swaps while playing\n\n| reply ms | shown / dropped (source, pipeline) with the swap | the same without |\n|---|---|---|\n";
    for w in &r.swaps {
        md += &format!(
            "| {:.0} | {} / {}, {} | {} / {}, {} |\n",
            w.reply_ms,
            w.with_swap.shown,
            w.with_swap.dropped_source,
            w.with_swap.dropped_pipeline,
            w.without.shown,
            w.without.dropped_source,
            w.without.dropped_pipeline
        );
    }
    md += "\n## The console under load\n\nEach round: a span without it, then one with the pages \
           and the OSC controller.\n\n| shown / dropped (source, pipeline) with the load | \
           without | status requests | camera images | events read | OSC sent / answered |\n\
           |---|---|---|---|---|---|\n";
    for c in &r.console {
        md += &format!(
            "| {} / {}, {} | {} / {}, {} | {} | {} | {} | {} / {} |\n",
            c.with_load.shown,
            c.with_load.dropped_source,
            c.with_load.dropped_pipeline,
            c.without.shown,
            c.without.dropped_source,
            c.without.dropped_pipeline,
            c.page_requests,
            c.camera_images,
            c.events_read,
            c.osc_sent,
            c.osc_replies
        );
    }
    let d = &r.drift;
    md += &format!(
        "\n## Drift\n\nBump {} px (of 800), monitoring every {} s: baseline {} dB, after the bump \
         {} dB; reported {}.\n",
        d.bump_px,
        d.period_s,
        d.baseline_psnr.map_or("-".into(), |v| format!("{v:.2}")),
        d.psnr_after.map_or("-".into(), |v| format!("{v:.2}")),
        match (d.detected_after_s, d.detected_after_periods) {
            (Some(s), Some(p)) => format!("{s:.2} s after the bump ({p:.2} periods)"),
            _ => "not within ten periods".into(),
        }
    );
    if let Some(t) = d.recovered_after_s {
        md += &format!(
            "On drift \"{}\": the new model ({} sampling images, verified {} dB) played {t:.1} s \
             after the detection; its first monitoring score {} dB.\n",
            d.on_drift,
            d.sampling_images.map_or("-".into(), |n| n.to_string()),
            d.verified_psnr.map_or("-".into(), |v| format!("{v:.2}")),
            d.psnr_recovered.map_or("-".into(), |v| format!("{v:.2}")),
        );
    }
    md += "\n## Stops\n\n";
    for st in &r.stops {
        md += &format!(
            "- {}: exited in {:.2} s with code {:?}\n",
            st.signal, st.seconds, st.exit_code
        );
    }
    md
}
