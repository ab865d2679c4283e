//! `compend serve`: the service (docs/architecture.md, "Service").
//!
//! Threads:
//! - the **main thread** runs the [`engine`]: it owns the devices (the projector window or the
//!   virtual rig's projector, the camera), the GPU pass and the model, and moves between the
//!   states idle, calibrating, training, verifying, playing and paused. Playback is the one
//!   playback loop ([`crate::player`]); between two refreshes (and between two
//!   captures while calibrating) the engine looks at its event channel, so a request is answered
//!   within a frame or a capture. Training runs on this thread too, off the async runtime;
//!   a calibration is cancelled at the next capture or phase ([`crate::calibrate::Options`]).
//! - a **tokio runtime** (two worker threads) serves the control socket ([`socket`]) and the
//!   signals: SIGTERM and SIGINT stop the service (exit 0 within seconds: a calibration stops
//!   at its next capture, nothing half-written, captures kept for the resume), SIGHUP reloads the
//!   configuration.
//! - the camera side of the virtual rig, and the video source, run on threads of their own
//!   (the playback loop's).
//!
//! `status` is answered by the socket tasks from a shared snapshot ([`Shared`]) the engine
//! updates, so it answers while the engine is busy training.

mod climb;
mod devices;
pub mod engine;
pub mod events;
pub mod http;
mod monitor;
pub mod notify;
mod opening;
pub mod osc;
pub mod protocol;
pub mod refusals;
mod screen;
pub mod socket;
pub mod views;

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::Receiver;
use std::sync::{Arc, Mutex, MutexGuard, mpsc};
use std::time::Instant;

use tokio::sync::oneshot;

use crate::config::{Config, RigKind};
use crate::error::{Error, Result};
use notify::Notifier;
use protocol::{Reply, Request, State, Status};

/// A request on its way to the engine, with where its reply goes.
pub struct Envelope {
    pub request: Request,
    pub reply: Option<oneshot::Sender<Reply>>,
    /// A `play` request's source, opened while the playback before went on.
    pub opened: Option<opening::Opened>,
}

impl Envelope {
    /// Sends the reply, if anyone still waits for it.
    pub fn answer(self, reply: Reply) {
        if let Some(tx) = self.reply {
            let _ = tx.send(reply);
        }
    }
}

/// What the engine is told.
pub enum Event {
    Request(Envelope),
    /// SIGHUP: the configuration file, parsed again.
    Reload(Box<Config>),
    /// The shutdown signal [`serve`] was given resolved (SIGTERM, SIGINT, a test's): what
    /// stopped it.
    Terminate(&'static str),
}

/// What the engine and the socket tasks share.
pub struct Shared {
    status: Mutex<Status>,
    events: mpsc::Sender<Event>,
    started: Instant,
    /// Set to stop a calibration at its next capture (stop requests and signals).
    pub cancel: Arc<AtomicBool>,
    /// Set once the service is shutting down.
    closing: AtomicBool,
    /// Set once the engine has stopped: the listeners and their clients stop ([`Shared::stopped`]).
    stop: tokio::sync::watch::Sender<bool>,
    /// What happened, for subscribers ([`events`]).
    pub hub: events::Hub,
    /// What the camera saw, for the console ([`views`]).
    pub views: views::Views,
}

impl Shared {
    fn new(rig: String, events: mpsc::Sender<Event>) -> Self {
        Self {
            status: Mutex::new(Status {
                state: State::Idle,
                version: env!("CARGO_PKG_VERSION").to_string(),
                pid: std::process::id(),
                uptime_s: 0.0,
                rig,
                model: None,
                source: None,
                media: None,
                frames: Default::default(),
                monitoring: Default::default(),
                calibration: None,
                calibrations: 0,
                last_calibration: None,
                last_climb: None,
                last_error: None,
                http: None,
                osc: None,
                setup: None,
                projectors: Vec::new(),
            }),
            events,
            started: Instant::now(),
            cancel: Arc::new(AtomicBool::new(false)),
            closing: AtomicBool::new(false),
            stop: tokio::sync::watch::Sender::new(false),
            hub: events::Hub::default(),
            views: views::Views::default(),
        }
    }

    fn lock(&self) -> MutexGuard<'_, Status> {
        // Every update is a plain assignment: a panic mid-update leaves a usable snapshot.
        self.status.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// A copy of the status, with the uptime.
    pub fn status(&self) -> Status {
        let mut s = self.lock().clone();
        s.uptime_s = self.started.elapsed().as_secs_f64();
        s
    }

    /// Changes the status, and publishes what the change moved ([`events::Watched`]).
    pub fn update(&self, f: impl FnOnce(&mut Status)) {
        let drafts = {
            let mut s = self.lock();
            let before = events::Watched::of(&s);
            f(&mut s);
            let after = events::Watched::of(&s);
            if after == before {
                return;
            }
            before.changes(&after, &s)
        };
        for d in drafts {
            self.hub.publish(d);
        }
    }

    /// Says in the log and to subscribers that `origin` asked `request` and how it ended.
    pub fn requested(&self, origin: &str, request: &Request, reply: &Reply) {
        let asked = serde_json::to_string(request).unwrap_or_else(|_| format!("{request:?}"));
        let asked = clipped(&asked);
        let outcome = match (&reply.error, &reply.message) {
            (Some(e), _) => format!("refused: {e}"),
            (None, Some(m)) => m.clone(),
            (None, None) => "done".to_string(),
        };
        let outcome = clipped(&outcome);
        if reply.ok {
            tracing::info!("request from {origin}: {asked}: {outcome}");
        } else {
            tracing::warn!("request from {origin}: {asked}: {outcome}");
        }
        let mut d = events::Draft::new(events::Kind::Request, format!("{asked}: {outcome}"));
        d.origin = Some(origin.to_string());
        d.ok = Some(reply.ok);
        self.hub.publish(d);
    }

    /// Sends a request to the engine; false once the service is shutting down. A `stop` also
    /// cancels a running calibration at once.
    pub fn send(&self, envelope: Envelope) -> bool {
        if self.closing.load(Ordering::Relaxed) {
            return false;
        }
        if envelope.request == Request::Stop {
            self.cancel.store(true, Ordering::Relaxed);
        }
        self.events.send(Event::Request(envelope)).is_ok()
    }

    /// Whether the engine has stopped ([`Shared::stopped`]).
    pub fn is_stopped(&self) -> bool {
        *self.stop.borrow()
    }

    /// Resolves once the engine has stopped: every listener stops accepting and every client
    /// task ends its connection (between requests), as mini-redis's shutdown does.
    pub async fn stopped(&self) {
        let mut rx = self.stop.subscribe();
        let _ = rx.wait_for(|stopped| *stopped).await;
    }

    fn signal(&self, event: Event) {
        if matches!(event, Event::Terminate(_)) {
            self.cancel.store(true, Ordering::Relaxed);
        }
        let _ = self.events.send(event);
    }
}

/// The engine's channel, shared state, systemd notifier and model-loading thread.
struct Io {
    shared: Arc<Shared>,
    rx: Receiver<Event>,
    notify: Notifier,
    loader: screen::Loader,
}

impl Io {
    fn state(&mut self, state: State, line: &str) {
        self.shared.update(|s| s.state = state);
        self.notify.status(line);
    }

    fn fail(&self, what: &str, e: &Error) {
        tracing::error!("{what}: {e}");
        let msg = format!("{what}: {e}");
        self.shared.update(|s| s.last_error = Some(msg));
    }

    /// Says in `status` how the progressive climb to `method` ended.
    fn climbed(&self, method: crate::model::Method, installed: bool, message: String) {
        self.shared.update(|s| {
            s.last_climb = Some(protocol::ClimbOutcome {
                method: method.name().to_string(),
                installed,
                message,
            })
        });
    }
}

/// Characters of a client-given text written to the log ([`clipped`]): its first
/// [`LOG_HEAD`] and last [`LOG_TAIL`].
const LOG_HEAD: usize = 100;
const LOG_TAIL: usize = 200;

/// `text` as the log shows it when a client chose it (a model path, an error that quotes one):
/// control characters escaped (`\n`, `\u{1b}`: a path cannot forge log lines or terminal
/// codes), whole when short, else its start and end around a note of how many characters were
/// left out, so that a long request cannot grow the log by more than a few hundred bytes per
/// line.
pub(crate) fn clipped(text: &str) -> std::borrow::Cow<'_, str> {
    let text: std::borrow::Cow<'_, str> = if text.chars().any(char::is_control) {
        text.chars()
            .map(|c| {
                if c.is_control() {
                    c.escape_default().collect()
                } else {
                    c.to_string()
                }
            })
            .collect::<String>()
            .into()
    } else {
        text.into()
    };
    let n = text.chars().count();
    if n <= LOG_HEAD + LOG_TAIL {
        return text;
    }
    let head: String = text.chars().take(LOG_HEAD).collect();
    let tail: String = text.chars().skip(n - LOG_TAIL).collect();
    format!(
        "{head}…[{} characters left out]…{tail}",
        n - LOG_HEAD - LOG_TAIL
    )
    .into()
}

/// What the service checks of its configuration's surroundings before it starts: the virtual
/// rig's scene loads at the configured sizes, the TCP token file reads, `[paths] model` is a
/// model directory or nothing yet (and can be written: `for_service`), and `[paths] state` and
/// `data` are folders or nothing yet. The first problem is an error naming the key or the path.
/// `compend config check`, which may run as another user than the service, leaves out what
/// needs the service's own access (`for_service` false): the token file is only looked up, and
/// the model path is not written to.
pub fn preflight(config: &Config, for_service: bool) -> Result<()> {
    let r = &config.rig;
    if matches!(r.kind, RigKind::Virtual | RigKind::Window) {
        let scene = crate::rig::scene::load(&r.scene)?;
        let cam = r.camera_size.unwrap_or(scene.camera.size());
        let prj = r.projector.unwrap_or(scene.projector.size());
        crate::rigs::check_sections(r, &scene)?;
        scene.with_resolution(cam, prj).validate()?;
    }
    let tokens = [
        (
            "[socket] tcp_token_file",
            config.socket.tcp.and(config.socket.tcp_token_file.as_ref()),
        ),
        (
            "[http] token_file",
            config.http.listen.and(config.http.token_file.as_ref()),
        ),
    ];
    let tls = config.http.listen.and(config.http.tls.as_ref());
    let tokens = tokens.into_iter().chain([
        ("[http] tls_cert", tls.map(|t| &t.cert)),
        ("[http] tls_key", tls.map(|t| &t.key)),
    ]);
    for (key, file) in tokens {
        let Some(file) = file else { continue };
        // A token file is read as the service reads it; `config check` run by a user who may
        // not read it (the service's own, mode 600) leaves it to the service.
        let readable = for_service
            || std::fs::File::open(file).is_ok_and(|f| f.metadata().is_ok_and(|m| m.is_file()));
        if readable && !key.contains("tls_") {
            socket::Token::read(file, key)?;
            continue;
        }
        match std::fs::metadata(file) {
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                return Err(Error::Input(format!(
                    "{key} = \"{}\": no such file",
                    file.display()
                )));
            }
            Ok(m) if !m.is_file() => {
                return Err(Error::Input(format!(
                    "{key} = \"{}\": not a plain file (a folder, a FIFO or a device)",
                    file.display()
                )));
            }
            _ => {}
        }
    }
    if config.http.listen.is_some() {
        http::tls_config(&config.http)?;
    }
    for (key, dir) in [
        ("[paths] state", &config.paths.state),
        ("[paths] data", &config.paths.data),
    ] {
        if dir.exists() && !dir.is_dir() {
            return Err(Error::Input(format!(
                "{key} = \"{}\": not a folder",
                dir.display()
            )));
        }
    }
    check_folders(&config.paths)?;
    socket::check_path(&config.socket.path)?;
    if for_service {
        crate::model::store::check_output(&config.paths.model)
    } else {
        crate::model::store::check_model_path(&config.paths.model)
    }
}

/// Folders of the system itself, which none of compend's folders may be (compend writes,
/// replaces and prunes in its own); anything under /proc, /sys and /dev neither.
const SYSTEM_FOLDERS: &[&str] = &[
    "/",
    "/bin",
    "/boot",
    "/dev",
    "/etc",
    "/home",
    "/lib",
    "/lib32",
    "/lib64",
    "/media",
    "/mnt",
    "/opt",
    "/proc",
    "/root",
    "/run",
    "/sbin",
    "/srv",
    "/sys",
    "/tmp",
    "/usr",
    "/usr/bin",
    "/usr/lib",
    "/usr/local",
    "/usr/sbin",
    "/usr/share",
    "/var",
    "/var/cache",
    "/var/lib",
    "/var/log",
    "/var/tmp",
];

/// `path` without `.` and with `..` taken back, as the kernel would walk it if no component
/// were a link; the folder's real path where it exists (links followed).
fn plain(path: &Path) -> PathBuf {
    if let Ok(real) = path.canonicalize() {
        return real;
    }
    let mut out = PathBuf::new();
    for c in path.components() {
        match c {
            std::path::Component::CurDir => {}
            std::path::Component::ParentDir => {
                out.pop();
            }
            c => out.push(c),
        }
    }
    out
}

/// The state, data and model folders are none of the system's, and do not overlap where it
/// breaks the service: the model folder is replaced whole at each install, so nothing else
/// may be inside it (a data folder there loses its runs, and the next start finds a model
/// folder that is not a model).
fn check_folders(paths: &crate::config::PathsConfig) -> Result<()> {
    let folders = [
        ("[paths] state", plain(&paths.state)),
        ("[paths] data", plain(&paths.data)),
        ("[paths] model", plain(&paths.model)),
    ];
    for (key, dir) in &folders {
        let system = SYSTEM_FOLDERS.iter().any(|f| dir == Path::new(f))
            || ["/proc", "/sys", "/dev"].iter().any(|f| dir.starts_with(f));
        if system {
            return Err(Error::Input(format!(
                "{key} = \"{}\": a folder of the system itself; give compend a folder of its \
                 own (e.g. /var/lib/compend)",
                dir.display()
            )));
        }
    }
    let [(_, state), (_, data), (_, model)] = &folders;
    for (key, dir) in [("[paths] state", state), ("[paths] data", data)] {
        if dir.starts_with(model) {
            return Err(Error::Input(format!(
                "{key} = \"{}\" is {} [paths] model = \"{}\", which is replaced whole at each \
                 install; put them side by side (e.g. STATE/calibration and STATE/model)",
                dir.display(),
                if dir == model {
                    "the same folder as"
                } else {
                    "inside"
                },
                model.display()
            )));
        }
    }
    Ok(())
}

/// How the service reads its configuration again on SIGHUP: the file with the command line's
/// overrides applied as at the start, so that what the command line set is not reported as
/// changed. `None`: no file to read again.
pub type Reload = Box<dyn Fn() -> Result<Config> + Send + Sync>;

/// Runs the service until it is stopped: a `stop` request, or `shutdown` resolving (the binary
/// passes [`terminated`]: SIGTERM or SIGINT; a test passes its own), which says what stopped it.
/// `reload` reads the configuration again on SIGHUP. When the engine has stopped, the socket,
/// the control port, the console and OSC stop accepting, their clients are told to go (each
/// ends its connection between requests), and they are waited for ([`STOP_GRACE`]) before this
/// returns; the socket file is removed.
pub fn serve(
    config: Config,
    reload: Option<Reload>,
    shutdown: impl std::future::Future<Output = &'static str> + Send + 'static,
) -> Result<()> {
    preflight(&config, true)?;
    let (tx, rx) = mpsc::channel();
    let rig_name = engine::rig_name(&config.rig);
    let shared = Arc::new(Shared::new(rig_name, tx));
    std::fs::create_dir_all(&config.paths.state)
        .map_err(|e| Error::io(&config.paths.state, "create state directory", e))?;
    // One service per state directory: two would calibrate into, prune and install into the
    // same folders. Held until this returns.
    let _lock = lock_state(&config.paths.state, "serve")?;
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .thread_name("compend-control")
        .enable_all()
        .build()
        .map_err(|e| Error::Failed(format!("cannot start the async runtime: {e}")))?;
    // The sockets first: a second service, or a path that is not ours, fails before any
    // device is opened. The TCP port before the Unix socket, which a failure would leave behind.
    let tcp = match (config.socket.tcp, &config.socket.tcp_token_file) {
        (Some(addr), Some(file)) => {
            let token = socket::Token::read(file, "[socket] tcp_token_file")?;
            let _guard = runtime.enter();
            Some((socket::bind_tcp(addr, "[socket] tcp")?, token, addr))
        }
        _ => None,
    };
    let console = {
        let _guard = runtime.enter();
        match http::bind(&config.http)? {
            Some(l) => Some((
                l,
                http::tls_config(&config.http)?,
                Arc::new(http::Console::new(&config.http, shared.clone())?),
            )),
            None => None,
        }
    };
    let osc = {
        let _guard = runtime.enter();
        osc::bind(&config.osc)?
    };
    let (listener, access) = {
        let _guard = runtime.enter();
        socket::bind(&config.socket)?
    };
    let socket_path = config.socket.path.clone();
    let mut tasks = vec![runtime.spawn(socket::serve(listener, access, shared.clone()))];
    if let Some((listener, token, addr)) = tcp {
        // The port bound (the configuration may ask for port 0: any free one).
        let addr = listener.local_addr().unwrap_or(addr);
        tracing::info!("control port: listening on {addr} (requests carry the token)");
        tasks.push(runtime.spawn(socket::serve_tcp(listener, token, shared.clone())));
    }
    if let Some((listener, tls, console)) = console {
        let addr = listener
            .local_addr()
            .map_or_else(|_| "?".to_string(), |a| a.to_string());
        let scheme = if tls.is_some() { "https" } else { "http" };
        tracing::info!("console: {scheme}://{addr}/");
        if tls.is_none() && config.http.listen.is_some_and(|a| !a.ip().is_loopback()) {
            tracing::warn!(
                "console: plain HTTP on {addr}: its token crosses the network in clear; set \
                 [http] tls_cert and tls_key, or reach it through SSH"
            );
        }
        shared.update(|s| s.http = Some(addr));
        tasks.push(runtime.spawn(http::serve(listener, tls, console)));
    }
    if let Some(sock) = osc {
        let addr = sock
            .local_addr()
            .map_or_else(|_| "?".to_string(), |a| a.to_string());
        tracing::info!(
            "osc: listening on udp {addr}; events to {} peer(s)",
            config.osc.peers.len()
        );
        shared.update(|s| s.osc = Some(addr));
        tasks.push(runtime.spawn(osc::serve(sock, config.osc.clone(), shared.clone())));
    }
    runtime.spawn(reloads(shared.clone(), reload));
    {
        let shared = shared.clone();
        runtime.spawn(async move {
            let why = shutdown.await;
            shared.signal(Event::Terminate(why));
        });
    }
    let result = engine::Engine::start(config, shared.clone(), rx).and_then(|engine| engine.run());
    shared.closing.store(true, Ordering::Relaxed);
    shared.stop.send_replace(true);
    runtime.block_on(async {
        let all = futures_util::future::join_all(tasks);
        if tokio::time::timeout(STOP_GRACE, all).await.is_err() {
            tracing::warn!(
                "stopping: a listener or a client was still busy after {} s; it is dropped",
                STOP_GRACE.as_secs_f64()
            );
        }
    });
    runtime.shutdown_timeout(std::time::Duration::from_secs(1));
    // The socket is ours (bind replaced only a dead one): remove it so clients see the service
    // is gone.
    let _ = std::fs::remove_file(&socket_path);
    result
}

/// The lock file in the state directory `state` (`compend.lock`), locked exclusively by `holder`
/// (`serve`, or `calibrate` with a `--config`) for as long as the returned file is kept; the
/// kernel lets it go when the process ends, however it ends. The file holds the pid and the
/// holder, for the message another one gets: an input error naming it. One process drives a
/// configuration's rig and writes into its state at a time: two would capture from one camera
/// and install into one model directory. A lock file this user cannot write (one root made) is
/// locked read-only ([`lock_state_if_held`]).
pub fn lock_state(state: &Path, holder: &str) -> Result<std::fs::File> {
    // A permission error is the operation's (exit 1), as the README says, not the input's.
    lock_state_if_held(state, holder)?.ok_or_else(|| Error::Io {
        path: state.join("compend.lock"),
        op: "make or read the lock file (run as the state directory's owner, or give another \
             --state)",
        source: std::io::Error::from(std::io::ErrorKind::PermissionDenied),
    })
}

/// [`lock_state`] for a process that may not be able to write `state` (`calibrate --config`
/// run by another user, its captures and model elsewhere): a lock file it cannot open for
/// writing is locked read-only (flock needs no write access); where there is none it can read
/// and none can be made, `None`: this user cannot tell whether a process holds it. Made by root,
/// the file is given to the directory's owner, so that the service can write it later.
pub fn lock_state_if_held(state: &Path, holder: &str) -> Result<Option<std::fs::File>> {
    use std::io::ErrorKind::{NotFound, PermissionDenied};
    use std::os::unix::fs::MetadataExt;
    let path = state.join("compend.lock");
    let opened = std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .create(true)
        .truncate(false)
        .open(&path);
    let (file, writable) = match opened {
        Ok(file) => {
            if nix::unistd::geteuid().is_root()
                && let (Ok(dir), Ok(meta)) = (state.metadata(), file.metadata())
                && meta.uid() != dir.uid()
            {
                std::os::unix::fs::fchown(&file, Some(dir.uid()), Some(dir.gid()))
                    .map_err(|e| Error::io(&path, "give the lock file to the state's owner", e))?;
            }
            (file, true)
        }
        Err(e) if e.kind() == PermissionDenied => match std::fs::File::open(&path) {
            Ok(file) => (file, false),
            Err(e) if matches!(e.kind(), NotFound | PermissionDenied) => return Ok(None),
            Err(e) => return Err(Error::io(&path, "open the state directory's lock file", e)),
        },
        Err(e) => return Err(Error::io(&path, "open the state directory's lock file", e)),
    };
    take_lock(file, writable, (state, "state directory"), holder).map(Some)
}

/// The lock of a calibration's data folder, held until dropped ([`lock_data`]).
#[derive(Debug)]
pub struct DataLock {
    _file: std::fs::File,
    dir: PathBuf,
    /// The folder was made for this lock: when nothing else went into it (the command failed
    /// before its first capture), the lock file and the folder go again, leaving nothing.
    made: bool,
}

impl Drop for DataLock {
    fn drop(&mut self) {
        if !self.made {
            return;
        }
        let only_lock = std::fs::read_dir(&self.dir).is_ok_and(|entries| {
            entries
                .filter_map(|e| e.ok())
                .all(|e| e.file_name() == "compend.lock")
        });
        if only_lock {
            let _ = std::fs::remove_file(self.dir.join("compend.lock"));
            let _ = std::fs::remove_dir(&self.dir);
        }
    }
}

/// The lock of a calibration's data folder `data` (`compend calibrate --data`), made if
/// missing: two calibrations capturing into one folder would mix their captures and both
/// install. The lock file is `DATA/compend.lock`, held as [`lock_state`] holds its own.
pub fn lock_data(data: &Path) -> Result<DataLock> {
    let made = !data.exists();
    std::fs::create_dir_all(data).map_err(|e| Error::io(data, "create the data folder", e))?;
    let path = data.join("compend.lock");
    let file = std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .create(true)
        .truncate(false)
        .open(&path)
        .map_err(|e| Error::io(&path, "open the data folder's lock file", e))?;
    let file = take_lock(file, true, (data, "data folder"), "calibrate")?;
    Ok(DataLock {
        _file: file,
        dir: data.to_path_buf(),
        made,
    })
}

/// Locks `file`, the lock file of `state`, for `holder`, and writes the pid and holder into it
/// when `writable`.
fn take_lock(
    mut file: std::fs::File,
    writable: bool,
    (state, what): (&Path, &str),
    holder: &str,
) -> Result<std::fs::File> {
    use std::io::Write;
    let path = state.join("compend.lock");
    match file.try_lock() {
        Ok(()) => {}
        Err(std::fs::TryLockError::WouldBlock) => {
            let text = std::fs::read_to_string(&path).unwrap_or_default();
            let mut words = text.split_whitespace();
            let pid = words.next().unwrap_or("unknown");
            // A lock written before the holder was recorded is a service's.
            let other = words.next().unwrap_or("serve");
            // A holder that could not write the file (another user's calibration) left an
            // older process's pid in it.
            let alive = pid
                .parse::<u32>()
                .is_ok_and(|p| Path::new(&format!("/proc/{p}")).exists());
            if !alive {
                return Err(Error::Input(format!(
                    "{}: another compend process holds this {what} (its lock file \
                     names pid {pid}, which no longer runs: the holder could not write it); \
                     wait for it to end",
                    state.display(),
                )));
            }
            let hint = match (holder, other) {
                ("serve", "serve") => {
                    "one service runs per state directory: stop that one, or give this one \
                     another --state"
                }
                ("serve", _) => "wait for the calibration to end, then start the service",
                (_, "serve") => {
                    "the running service calibrates on request (`compend recalibrate`); or stop \
                     it first"
                }
                _ => "wait for that calibration to end",
            };
            return Err(Error::Input(format!(
                "{}: `compend {other}` (pid {pid}) holds this {what}; {hint}",
                state.display(),
            )));
        }
        Err(std::fs::TryLockError::Error(e)) => {
            return Err(Error::io(&path, "lock the folder", e));
        }
    }
    if writable {
        file.set_len(0)
            .and_then(|()| writeln!(file, "{} {holder}", std::process::id()))
            .map_err(|e| Error::io(&path, "write the pid to", e))?;
    }
    Ok(file)
}

/// How long [`serve`] waits, once the engine has stopped, for the listeners and their clients
/// to end.
pub const STOP_GRACE: std::time::Duration = std::time::Duration::from_secs(2);

/// The binary's shutdown signal for [`serve`]: resolves at SIGTERM or SIGINT, naming it. Where
/// the handlers cannot be installed it never resolves (the service then stops on a `stop`
/// request), and says so.
pub async fn terminated() -> &'static str {
    use tokio::signal::unix::{SignalKind, signal};
    let (Ok(mut term), Ok(mut int)) = (
        signal(SignalKind::terminate()),
        signal(SignalKind::interrupt()),
    ) else {
        tracing::error!("cannot install the signal handlers; stop the service with compend stop");
        return std::future::pending().await;
    };
    tokio::select! {
        _ = term.recv() => "SIGTERM",
        _ = int.recv() => "SIGINT",
    }
}

/// SIGHUP reloads the configuration (with `reload`; without, it says there is nothing to read).
async fn reloads(shared: Arc<Shared>, reload: Option<Reload>) {
    use tokio::signal::unix::{SignalKind, signal};
    let Ok(mut hup) = signal(SignalKind::hangup()) else {
        tracing::error!("cannot install the SIGHUP handler; restart the service to reload");
        return;
    };
    while hup.recv().await.is_some() {
        match &reload {
            None => tracing::warn!("SIGHUP: no --config file to reload; nothing changed"),
            Some(reload) => match reload() {
                Ok(c) => shared.signal(Event::Reload(Box::new(c))),
                Err(e) => {
                    // In `status` too: the operator who sent the signal looks there.
                    let msg = format!(
                        "SIGHUP: the configuration was not reloaded, the running one stays: {e}"
                    );
                    tracing::error!("{msg}");
                    shared.update(|s| s.last_error = Some(msg));
                }
            },
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn long_client_text_is_clipped_for_the_log() {
        assert_eq!(clipped("/var/lib/compend/model"), "/var/lib/compend/model");
        let exact = "é".repeat(LOG_HEAD + LOG_TAIL);
        assert_eq!(clipped(&exact), exact.as_str());
        // Multi-byte characters are cut between characters, start and end kept.
        let long = format!("/{}: not found", "é".repeat(4000));
        let c = clipped(&long);
        assert!(c.starts_with("/éé") && c.ends_with("éé: not found"), "{c}");
        assert!(
            c.contains(&format!("[{} characters left out]", 4012 - 300)),
            "{c}"
        );
        assert_eq!(
            c.chars().count(),
            300 + "…[3712 characters left out]…".chars().count()
        );
        // A line break or an escape sequence in a path is written as its escape.
        assert_eq!(
            clipped("/a\nINFO forged\u{1b}[31m"),
            "/a\\nINFO forged\\u{1b}[31m"
        );
    }
}
