//! The operator's console over HTTP (`[http] listen`), on the service's tokio runtime: the page
//! itself (one HTML file in the binary, no third-party assets), the status, the event stream
//! (Server-Sent Events), the requests of the control socket as JSON POSTs, the camera's latest
//! frame and the last monitoring check's images as JPEG, and Prometheus metrics.
//!
//! With `[http] tls_cert` and `tls_key` it speaks HTTPS (rustls), each handshake on a task of
//! its own with [`HANDSHAKE_TIMEOUT`].
//!
//! Access: a client on this machine (loopback) may do everything. A client from elsewhere must
//! come from a network in `[http] allow` and carry the token of `[http] token_file` (an
//! `Authorization: Bearer` header, or the cookie the login page sets). Requests that change
//! anything are POSTs that must carry the header `X-Compend: 1` (a page of another site cannot
//! send it without a CORS preflight compend never answers) and, when the browser sends an
//! `Origin`, come from this very host. A connection that sends nothing for
//! [`FIRST_BYTE_TIMEOUT`] is closed, and so is one with no byte either way for [`IDLE_TIMEOUT`]
//! (an idle keep-alive connection would otherwise hold its slot for good). At most [`MAX_CONNECTIONS`] connections and
//! [`MAX_SUBSCRIBERS`] event streams (over every surface) are served at once; request bodies are capped at
//! [`crate::service::protocol::MAX_REQUEST_BYTES`]. Everything here runs on the runtime's
//! threads: nothing a client does waits on the render loop, except a request's answer, which
//! the engine gives between two refreshes.

use std::convert::Infallible;
use std::future::Future;
use std::net::SocketAddr;
use std::pin::Pin;
use std::sync::{Arc, Mutex};
use std::task::{Context, Poll};
use std::time::Duration;

use axum::Router;
use axum::body::Bytes;
use axum::extract::connect_info::Connected;
use axum::extract::{
    ConnectInfo, DefaultBodyLimit, Path as UrlPath, Request as HttpRequest, State,
};
use axum::http::{HeaderMap, HeaderValue, StatusCode, header};
use axum::middleware::{self, Next};
use axum::response::sse::{Event as SseEvent, KeepAlive, Sse};
use axum::response::{IntoResponse, Redirect, Response};
use axum::routing::{get, post};
use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::{OwnedSemaphorePermit, Semaphore, broadcast};

use super::Shared;
use super::events::{Event, MAX_SUBSCRIBERS};
use super::protocol::{MAX_REQUEST_BYTES, Reply, Request, State as ServiceState, Status};
use super::refusals::Refusals;
use super::socket::Token;
use super::views::{self, Rgb8};
use crate::config::HttpConfig;
use crate::error::{Error, Result};

/// Connections served at once; more wait in the kernel's queue.
pub const MAX_CONNECTIONS: usize = 64;
/// JPEG quality of the camera images.
const JPEG_QUALITY: u8 = 80;
/// The login cookie's name.
const COOKIE: &str = "compend_token";

/// The page (HTML, CSS and script in one file).
const PAGE: &str = include_str!("console.html");

/// Binds `[http] listen`; None when it is off. An address in use is an input error naming the
/// key ([`super::socket::bind_tcp`]).
pub fn bind(cfg: &HttpConfig) -> Result<Option<TcpListener>> {
    let Some(addr) = cfg.listen else {
        return Ok(None);
    };
    super::socket::bind_tcp(addr, "[http] listen").map(Some)
}

/// What the handlers share.
pub struct Console {
    shared: Arc<Shared>,
    token: Option<Token>,
    allow: Vec<ipnet::IpNet>,
    /// Served over TLS (the login cookie is then `Secure`).
    tls: bool,
    /// The last camera JPEG made, by the frame's number: many pages, one encoding.
    jpeg: Mutex<Option<(u64, Bytes)>>,
    /// Peers refused (outside `[http] allow`, a wrong token): backed off, their log summarised.
    refusals: Refusals,
}

impl Console {
    /// The console for `cfg`; reads the token file when there is one.
    pub fn new(cfg: &HttpConfig, shared: Arc<Shared>) -> Result<Self> {
        let token = cfg
            .token_file
            .as_deref()
            .map(|f| Token::read(f, "[http] token_file"))
            .transpose()?;
        Ok(Self {
            shared,
            token,
            allow: cfg.allow.clone(),
            tls: cfg.tls.is_some(),
            jpeg: Mutex::new(None),
            refusals: Refusals::new("console"),
        })
    }
}

/// How long a client may take over its TLS handshake.
const HANDSHAKE_TIMEOUT: Duration = Duration::from_secs(10);

/// The TLS settings of `[http] tls_cert` and `tls_key`; None without them. A file that is
/// missing, not PEM, or holds no certificate or no key is an input error naming the key.
pub fn tls_config(cfg: &HttpConfig) -> Result<Option<Arc<rustls::ServerConfig>>> {
    use rustls::pki_types::pem::PemObject;
    use rustls::pki_types::{CertificateDer, PrivateKeyDer};
    let Some(files) = &cfg.tls else {
        return Ok(None);
    };
    let bad = |key: &str, path: &std::path::Path, what: String| {
        Error::Input(format!("[http] {key} = \"{}\": {what}", path.display()))
    };
    let certs: Vec<CertificateDer<'static>> = CertificateDer::pem_file_iter(&files.cert)
        .map_err(|e| {
            bad(
                "tls_cert",
                &files.cert,
                format!("cannot read it as PEM: {e}"),
            )
        })?
        .collect::<std::result::Result<_, _>>()
        .map_err(|e| {
            bad(
                "tls_cert",
                &files.cert,
                format!("not a PEM certificate chain: {e}"),
            )
        })?;
    if certs.is_empty() {
        return Err(bad(
            "tls_cert",
            &files.cert,
            "holds no certificate (expected -----BEGIN CERTIFICATE-----)".into(),
        ));
    }
    let key = PrivateKeyDer::from_pem_file(&files.key).map_err(|e| {
        bad(
            "tls_key",
            &files.key,
            format!("no private key in it (expected a PEM PRIVATE KEY): {e}"),
        )
    })?;
    let config = rustls::ServerConfig::builder_with_provider(Arc::new(
        rustls::crypto::ring::default_provider(),
    ))
    .with_safe_default_protocol_versions()
    .and_then(|b| b.with_no_client_auth().with_single_cert(certs, key))
    .map_err(|e| {
        bad(
            "tls_key",
            &files.key,
            format!("does not go with the certificate of tls_cert: {e}"),
        )
    })?;
    Ok(Some(Arc::new(config)))
}

/// A connection: plain, or TLS over TCP.
enum Stream {
    Plain(TcpStream),
    Tls(Box<tokio_rustls::server::TlsStream<TcpStream>>),
}

/// How long a new connection may stay silent before its first byte: one that sends nothing
/// (a client that leaked it, or a slow attack) gives its slot back.
const FIRST_BYTE_TIMEOUT: Duration = Duration::from_secs(5);

/// How long a connection may stay without a byte either way (an idle keep-alive connection)
/// before it is closed and its slot given back. An event stream is never that quiet: it sends
/// a keep-alive comment every 15 s.
const IDLE_TIMEOUT: Duration = Duration::from_secs(20);

/// A connection holding its slot until it closes.
struct CappedIo {
    io: Stream,
    _slot: OwnedSemaphorePermit,
    /// Until the first byte has come: when the connection is closed if none has.
    first_byte_by: Option<Pin<Box<tokio::time::Sleep>>>,
    /// When the connection is closed if no byte comes or goes before.
    idle_by: Pin<Box<tokio::time::Sleep>>,
}

impl CappedIo {
    fn new(io: Stream, slot: OwnedSemaphorePermit) -> Self {
        Self {
            io,
            _slot: slot,
            first_byte_by: Some(Box::pin(tokio::time::sleep(FIRST_BYTE_TIMEOUT))),
            idle_by: Box::pin(tokio::time::sleep(IDLE_TIMEOUT)),
        }
    }

    /// A byte came or went: the idle deadline moves on.
    fn active(&mut self) {
        self.idle_by
            .as_mut()
            .reset(tokio::time::Instant::now() + IDLE_TIMEOUT);
    }
}

impl AsyncRead for CappedIo {
    fn poll_read(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<std::io::Result<()>> {
        let before = buf.filled().len();
        let polled = match &mut self.io {
            Stream::Plain(s) => Pin::new(s).poll_read(cx, buf),
            Stream::Tls(s) => Pin::new(s.as_mut()).poll_read(cx, buf),
        };
        match &polled {
            Poll::Ready(_) if buf.filled().len() > before => {
                self.first_byte_by = None;
                self.active();
            }
            Poll::Pending => {
                if let Some(deadline) = self.first_byte_by.as_mut()
                    && deadline.as_mut().poll(cx).is_ready()
                {
                    return Poll::Ready(Err(std::io::Error::new(
                        std::io::ErrorKind::TimedOut,
                        "no request within the first seconds",
                    )));
                }
                if self.idle_by.as_mut().poll(cx).is_ready() {
                    return Poll::Ready(Err(std::io::Error::new(
                        std::io::ErrorKind::TimedOut,
                        "idle: no byte either way for a while",
                    )));
                }
            }
            Poll::Ready(_) => {}
        }
        polled
    }
}

impl AsyncWrite for CappedIo {
    fn poll_write(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &[u8],
    ) -> Poll<std::io::Result<usize>> {
        let polled = match &mut self.io {
            Stream::Plain(s) => Pin::new(s).poll_write(cx, buf),
            Stream::Tls(s) => Pin::new(s.as_mut()).poll_write(cx, buf),
        };
        if matches!(polled, Poll::Ready(Ok(n)) if n > 0) {
            self.active();
        }
        polled
    }

    fn poll_flush(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        match &mut self.io {
            Stream::Plain(s) => Pin::new(s).poll_flush(cx),
            Stream::Tls(s) => Pin::new(s.as_mut()).poll_flush(cx),
        }
    }

    fn poll_shutdown(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        match &mut self.io {
            Stream::Plain(s) => Pin::new(s).poll_shutdown(cx),
            Stream::Tls(s) => Pin::new(s.as_mut()).poll_shutdown(cx),
        }
    }
}

/// A listener that serves at most [`MAX_CONNECTIONS`] connections at once (more wait in the
/// kernel's queue), their TLS handshakes done on tasks of their own so that a slow client does
/// not hold up the others.
struct Capped {
    ready: tokio::sync::mpsc::Receiver<(CappedIo, SocketAddr)>,
    local: SocketAddr,
}

impl Capped {
    fn start(inner: TcpListener, tls: Option<Arc<rustls::ServerConfig>>) -> std::io::Result<Self> {
        let local = inner.local_addr()?;
        let (tx, ready) = tokio::sync::mpsc::channel(MAX_CONNECTIONS);
        let slots = Arc::new(Semaphore::new(MAX_CONNECTIONS));
        let acceptor = tls.map(tokio_rustls::TlsAcceptor::from);
        tokio::spawn(async move {
            loop {
                let Ok(slot) = slots.clone().acquire_owned().await else {
                    return;
                };
                let (io, addr) = match inner.accept().await {
                    Ok(got) => got,
                    Err(e) => {
                        // Out of file descriptors, a connection reset before it was taken:
                        // wait a little and go on.
                        tracing::debug!("console: accept: {e}");
                        tokio::time::sleep(Duration::from_millis(50)).await;
                        continue;
                    }
                };
                let _ = io.set_nodelay(true);
                let tx = tx.clone();
                match &acceptor {
                    None => {
                        let conn = CappedIo::new(Stream::Plain(io), slot);
                        if tx.send((conn, addr)).await.is_err() {
                            return;
                        }
                    }
                    Some(acceptor) => {
                        let acceptor = acceptor.clone();
                        tokio::spawn(async move {
                            match tokio::time::timeout(HANDSHAKE_TIMEOUT, acceptor.accept(io)).await
                            {
                                Ok(Ok(tls)) => {
                                    let conn = CappedIo::new(Stream::Tls(Box::new(tls)), slot);
                                    let _ = tx.send((conn, addr)).await;
                                }
                                Ok(Err(e)) => {
                                    tracing::debug!("console: TLS handshake with {addr}: {e}")
                                }
                                Err(_) => tracing::debug!(
                                    "console: {addr} did not finish its TLS handshake"
                                ),
                            }
                        });
                    }
                }
            }
        });
        Ok(Self { ready, local })
    }
}

impl axum::serve::Listener for Capped {
    type Io = CappedIo;
    type Addr = SocketAddr;

    async fn accept(&mut self) -> (Self::Io, Self::Addr) {
        match self.ready.recv().await {
            Some(conn) => conn,
            // The accepting task ended (the runtime is shutting down): no more connections.
            None => std::future::pending().await,
        }
    }

    fn local_addr(&self) -> std::io::Result<Self::Addr> {
        Ok(self.local)
    }
}

/// The client's address.
#[derive(Clone, Copy, Debug)]
struct Peer(SocketAddr);

impl Connected<axum::serve::IncomingStream<'_, Capped>> for Peer {
    fn connect_info(stream: axum::serve::IncomingStream<'_, Capped>) -> Self {
        Peer(*stream.remote_addr())
    }
}

/// Serves the console on `listener` (HTTPS with `tls`) until the runtime shuts down.
pub async fn serve(
    listener: TcpListener,
    tls: Option<Arc<rustls::ServerConfig>>,
    console: Arc<Console>,
) {
    let shared = console.shared.clone();
    let app = router(console);
    let capped = match Capped::start(listener, tls) {
        Ok(c) => c,
        Err(e) => {
            tracing::error!("console: cannot serve: {e}");
            return;
        }
    };
    // Once the service stops: no new connections, and the open ones are waited for (an event
    // stream is cut when the runtime ends).
    let served = axum::serve(capped, app.into_make_service_with_connect_info::<Peer>())
        .with_graceful_shutdown(async move { shared.stopped().await });
    if let Err(e) = served.await {
        tracing::error!("console: the HTTP server stopped: {e}");
    }
}

fn router(console: Arc<Console>) -> Router {
    Router::new()
        .route("/", get(page))
        .route("/login", get(login_page).post(login))
        .route("/api/status", get(status))
        .route("/api/events", get(events))
        .route("/api/log", get(log))
        .route("/api/request", post(request))
        .route("/api/camera.jpg", get(camera))
        .route("/api/check/{which}", get(check_image))
        .route("/api/model/unreachable.png", get(unreachable))
        .route("/api/model/fov.png", get(fov))
        .route("/metrics", get(metrics))
        .layer(DefaultBodyLimit::max(MAX_REQUEST_BYTES))
        .layer(middleware::from_fn_with_state(console.clone(), guard))
        .with_state(console)
}

/// An error response: a status and one line of text.
fn refuse(code: StatusCode, text: impl Into<String>) -> Response {
    (
        code,
        [(header::CONTENT_TYPE, "text/plain; charset=utf-8")],
        text.into() + "\n",
    )
        .into_response()
}

/// Who may ask what (the module's comment): checked before any handler runs.
async fn guard(
    State(c): State<Arc<Console>>,
    ConnectInfo(Peer(peer)): ConnectInfo<Peer>,
    req: HttpRequest,
    next: Next,
) -> Response {
    let ip = peer.ip().to_canonical();
    let local = ip.is_loopback();
    let who = ip.to_string();
    if !local && let Err(why) = c.refusals.admit(&who) {
        return refuse(StatusCode::TOO_MANY_REQUESTS, why);
    }
    if !local && !c.allow.iter().any(|n| n.contains(&ip)) {
        c.refusals.refused(&who, "not in [http] allow");
        return refuse(
            StatusCode::FORBIDDEN,
            format!("{ip} may not use this console: it is not in [http] allow"),
        );
    }
    let path = req.uri().path().to_string();
    if !local && path != "/login" {
        let token = c.token.as_ref();
        let given = bearer(req.headers()).or_else(|| cookie(req.headers(), COOKIE));
        let ok = match (token, given) {
            (Some(t), Some(g)) => t.matches(g.as_bytes()),
            _ => false,
        };
        if !ok {
            if req.method() == axum::http::Method::GET && path == "/" {
                return Redirect::to("/login").into_response();
            }
            c.refusals
                .refused(&who, &format!("{path}: no token, or the wrong one"));
            return refuse(
                StatusCode::UNAUTHORIZED,
                "this console needs its token: an Authorization: Bearer header, or log in at \
                 /login",
            );
        }
        c.refusals.accepted(&who);
    }
    if req.method() == axum::http::Method::POST {
        if let Err(why) = same_origin(req.headers()) {
            tracing::warn!("console: refused a POST from {peer} to {path}: {why}");
            return refuse(StatusCode::FORBIDDEN, why);
        }
        if path != "/login" && req.headers().get("x-compend").is_none_or(|v| v != "1") {
            return refuse(
                StatusCode::FORBIDDEN,
                "a request that changes something carries the header X-Compend: 1",
            );
        }
    }
    next.run(req).await
}

/// The token of an `Authorization: Bearer` header.
fn bearer(h: &HeaderMap) -> Option<String> {
    h.get(header::AUTHORIZATION)?
        .to_str()
        .ok()?
        .strip_prefix("Bearer ")
        .map(|t| t.trim().to_string())
}

/// The value of cookie `name`.
fn cookie(h: &HeaderMap, name: &str) -> Option<String> {
    h.get_all(header::COOKIE)
        .iter()
        .filter_map(|v| v.to_str().ok())
        .flat_map(|v| v.split(';'))
        .filter_map(|kv| kv.trim().split_once('='))
        .find(|(k, _)| *k == name)
        .map(|(_, v)| v.to_string())
}

/// A browser's `Origin`, when it sends one, names this host (the `Host` it asked).
fn same_origin(h: &HeaderMap) -> std::result::Result<(), String> {
    let Some(origin) = h.get(header::ORIGIN) else {
        return Ok(());
    };
    let origin = origin.to_str().unwrap_or("");
    let host = h
        .get(header::HOST)
        .and_then(|v| v.to_str().ok())
        .unwrap_or("");
    let bare = origin
        .strip_prefix("http://")
        .or_else(|| origin.strip_prefix("https://"))
        .unwrap_or("");
    if !host.is_empty() && bare == host {
        Ok(())
    } else {
        Err(format!(
            "a request from the page of another site ({origin}) is refused; use this console's \
             own page"
        ))
    }
}

fn no_store(mut r: Response) -> Response {
    r.headers_mut()
        .insert(header::CACHE_CONTROL, HeaderValue::from_static("no-store"));
    r
}

async fn page() -> Response {
    let mut r = ([(header::CONTENT_TYPE, "text/html; charset=utf-8")], PAGE).into_response();
    let h = r.headers_mut();
    h.insert(
        header::CONTENT_SECURITY_POLICY,
        HeaderValue::from_static(
            "default-src 'self'; img-src 'self' data: blob:; style-src 'self' 'unsafe-inline'; \
             script-src 'self' 'unsafe-inline'; connect-src 'self'; frame-ancestors 'none'",
        ),
    );
    h.insert(header::X_FRAME_OPTIONS, HeaderValue::from_static("DENY"));
    no_store(r)
}

const LOGIN: &str = r#"<!doctype html><html lang="en"><meta charset="utf-8">
<title>compend: log in</title>
<body style="font-family:sans-serif;max-width:30em;margin:4em auto">
<h1>compend</h1><p>This console needs the token of <code>[http] token_file</code>.</p>
<form method="post" action="/login"><input type="password" name="token" autofocus
 style="width:100%"><p><button>Log in</button></p></form></body></html>"#;

async fn login_page() -> Response {
    no_store(([(header::CONTENT_TYPE, "text/html; charset=utf-8")], LOGIN).into_response())
}

#[derive(serde::Deserialize)]
struct LoginForm {
    token: String,
}

async fn login(
    State(c): State<Arc<Console>>,
    ConnectInfo(Peer(peer)): ConnectInfo<Peer>,
    axum::Form(form): axum::Form<LoginForm>,
) -> Response {
    match &c.token {
        Some(t) if t.matches(form.token.as_bytes()) => {
            c.refusals.accepted(&peer.ip().to_canonical().to_string());
            tracing::info!("console: {peer} logged in");
            let mut r = Redirect::to("/").into_response();
            let secure = if c.tls { "; Secure" } else { "" };
            if let Ok(v) = HeaderValue::from_str(&format!(
                "{COOKIE}={}; HttpOnly; SameSite=Strict; Path=/{secure}",
                form.token
            )) {
                r.headers_mut().insert(header::SET_COOKIE, v);
            }
            r
        }
        Some(_) => {
            let who = peer.ip().to_canonical().to_string();
            c.refusals.refused(&who, "a login with the wrong token");
            refuse(StatusCode::UNAUTHORIZED, "wrong token")
        }
        None => Redirect::to("/").into_response(),
    }
}

async fn status(State(c): State<Arc<Console>>) -> Response {
    no_store(axum::Json(c.shared.status()).into_response())
}

/// The kept events and monitoring scores, for a page that just opened.
async fn log(State(c): State<Arc<Console>>) -> Response {
    let hub = &c.shared.hub;
    let body = serde_json::json!({
        "events": hub.recent(),
        "scores": hub.scores(),
    });
    no_store(axum::Json(body).into_response())
}

/// Every event from now on, one SSE `data:` line of JSON each; a subscriber that fell behind
/// gets an event of kind `lagged` with the number it missed.
async fn events(State(c): State<Arc<Console>>) -> Response {
    let Some(slot) = c.shared.hub.slot() else {
        return refuse(
            StatusCode::SERVICE_UNAVAILABLE,
            format!("{MAX_SUBSCRIBERS} event streams are open already; close one"),
        );
    };
    let rx = c.shared.hub.subscribe();
    let shared = c.shared.clone();
    // Ends when the service stops, so that the server's graceful shutdown is not held up.
    let stream = futures_util::stream::unfold((rx, slot), move |(mut rx, slot)| {
        let shared = shared.clone();
        async move {
            let got = tokio::select! {
                got = rx.recv() => got,
                () = shared.stopped() => return None,
            };
            let item = match got {
                Ok(e) => sse(&e),
                Err(broadcast::error::RecvError::Lagged(n)) => Ok(SseEvent::default()
                    .event("lagged")
                    .data(format!("{{\"kind\":\"lagged\",\"missed\":{n}}}"))),
                Err(broadcast::error::RecvError::Closed) => return None,
            };
            Some((item, (rx, slot)))
        }
    });
    no_store(
        Sse::new(stream)
            .keep_alive(KeepAlive::new().interval(Duration::from_secs(15)))
            .into_response(),
    )
}

fn sse(e: &Event) -> std::result::Result<SseEvent, Infallible> {
    Ok(SseEvent::default()
        .id(e.seq.to_string())
        .data(serde_json::to_string(e).unwrap_or_default()))
}

/// A request as on the control socket (one JSON object); the reply as the socket gives it.
async fn request(
    State(c): State<Arc<Console>>,
    ConnectInfo(Peer(peer)): ConnectInfo<Peer>,
    body: Bytes,
) -> Response {
    let (parsed, id) = Request::parse_with_id(&body);
    let request = match parsed {
        Ok(r) => r,
        Err(e) => {
            let mut reply = Reply::error(e);
            reply.request_id = id;
            return (StatusCode::BAD_REQUEST, axum::Json(reply)).into_response();
        }
    };
    let mut reply = super::socket::dispatch(request, &c.shared, &format!("http {peer}")).await;
    reply.request_id = id;
    no_store(axum::Json(reply).into_response())
}

fn jpeg_response(bytes: Bytes) -> Response {
    no_store(([(header::CONTENT_TYPE, "image/jpeg")], bytes).into_response())
}

/// Encodes `img` off the runtime's threads.
async fn encode(img: Arc<Rgb8>) -> std::result::Result<Bytes, Response> {
    tokio::task::spawn_blocking(move || img.jpeg(JPEG_QUALITY))
        .await
        .map_err(|e| refuse(StatusCode::INTERNAL_SERVER_ERROR, e.to_string()))?
        .map(Bytes::from)
        .map_err(|e| refuse(StatusCode::INTERNAL_SERVER_ERROR, e))
}

/// The camera's latest frame kept (at most [`views::CAMERA_FPS`] a second).
async fn camera(State(c): State<Arc<Console>>) -> Response {
    let Some(kept) = c.shared.views.camera() else {
        return refuse(
            StatusCode::NOT_FOUND,
            "no camera frame yet (the camera is seen while calibrating and playing)",
        );
    };
    if let Some((seq, bytes)) = &*c.jpeg.lock().unwrap_or_else(|e| e.into_inner())
        && *seq == kept.seq
    {
        return jpeg_response(bytes.clone());
    }
    match encode(kept.image).await {
        Ok(bytes) => {
            *c.jpeg.lock().unwrap_or_else(|e| e.into_inner()) = Some((kept.seq, bytes.clone()));
            jpeg_response(bytes)
        }
        Err(r) => r,
    }
}

/// The last monitoring check: `desired.jpg`, `seen.jpg`, `difference.jpg` (a heat map), or
/// `area.json`, its displayable area (camera pixels).
async fn check_image(State(c): State<Arc<Console>>, UrlPath(which): UrlPath<String>) -> Response {
    let Some(pair) = c.shared.views.pair() else {
        return refuse(
            StatusCode::NOT_FOUND,
            "no monitoring check yet (one is made every [monitoring] period_s while playing)",
        );
    };
    let img = match which.as_str() {
        "area.json" => {
            let a = pair.area;
            return no_store(
                axum::Json(serde_json::json!({
                    "x": a.x, "y": a.y, "width": a.width, "height": a.height,
                    "camera": [pair.seen.width, pair.seen.height],
                }))
                .into_response(),
            );
        }
        "desired.jpg" => pair.desired,
        "seen.jpg" => pair.seen,
        "difference.jpg" => match views::heat_map(&pair.desired, &pair.seen, pair.area) {
            Ok(h) => Arc::new(h),
            Err(e) => return refuse(StatusCode::INTERNAL_SERVER_ERROR, e),
        },
        other => {
            return refuse(
                StatusCode::NOT_FOUND,
                format!("{other}: expected desired.jpg, seen.jpg, difference.jpg or area.json"),
            );
        }
    };
    match encode(img).await {
        Ok(bytes) => jpeg_response(bytes),
        Err(r) => r,
    }
}

/// The served model's map of where its calibration found the surface cannot be compensated
/// (camera pixels: blue shadowed, magenta saturated, red too dark, yellow too bright, the rest
/// of the displayable area as the white capture shows it, outside it dimmed): the calibration's
/// own `cam/unreachable.png`, read from the model's record, never from a path a client names.
async fn unreachable(State(c): State<Arc<Console>>) -> Response {
    let Some(setup) = c.shared.status().model.and_then(|m| m.setup) else {
        return refuse(
            StatusCode::NOT_FOUND,
            "the served model records no calibration captures (calibrate to make one)",
        );
    };
    let path = crate::dataset::unreachable_path_of(&setup);
    let read = {
        let path = path.clone();
        tokio::task::spawn_blocking(move || std::fs::read(path)).await
    };
    match read.unwrap_or_else(|e| Err(std::io::Error::other(e.to_string()))) {
        Ok(bytes) => no_store(([(header::CONTENT_TYPE, "image/png")], bytes).into_response()),
        Err(e) => refuse(
            StatusCode::NOT_FOUND,
            format!("{}: {e} (a calibration writes it)", path.display()),
        ),
    }
}

/// The served model's projector field of view, to lay over the camera view (camera pixels,
/// RGBA PNG: clear inside, dimmed outside, its edge drawn; [`views::fov_overlay`]).
async fn fov(State(c): State<Arc<Console>>) -> Response {
    let Some(mask) = c.shared.views.fov() else {
        return refuse(
            StatusCode::NOT_FOUND,
            "no model is served yet (calibrate to make one)",
        );
    };
    let encoded = tokio::task::spawn_blocking(move || {
        let rgba = views::fov_overlay(&mask);
        let mut out = Vec::new();
        image::ImageEncoder::write_image(
            image::codecs::png::PngEncoder::new(&mut out),
            &rgba,
            mask.width() as u32,
            mask.height() as u32,
            image::ExtendedColorType::Rgba8,
        )
        .map(|()| out)
        .map_err(|e| format!("PNG of the field of view: {e}"))
    })
    .await
    .unwrap_or_else(|e| Err(e.to_string()));
    match encoded {
        Ok(bytes) => no_store(([(header::CONTENT_TYPE, "image/png")], bytes).into_response()),
        Err(e) => refuse(StatusCode::INTERNAL_SERVER_ERROR, e),
    }
}

async fn metrics(State(c): State<Arc<Console>>) -> Response {
    let text = prometheus_text(&c.shared.status());
    no_store(
        (
            [(
                header::CONTENT_TYPE,
                "text/plain; version=0.0.4; charset=utf-8",
            )],
            text,
        )
            .into_response(),
    )
}

/// Writes the Prometheus text format: each metric's HELP and TYPE once, then its samples.
struct Exposition(String);

impl Exposition {
    fn metric(&mut self, name: &str, kind: &str, help: &str) {
        use std::fmt::Write;
        let _ = writeln!(self.0, "# HELP compend_{name} {help}");
        let _ = writeln!(self.0, "# TYPE compend_{name} {kind}");
    }

    fn sample(&mut self, name: &str, labels: &[(&str, &str)], value: f64) {
        use std::fmt::Write;
        let labels = if labels.is_empty() {
            String::new()
        } else {
            let inner: Vec<String> = labels
                .iter()
                .map(|(k, v)| format!("{k}=\"{}\"", escape_label(v)))
                .collect();
            format!("{{{}}}", inner.join(","))
        };
        let _ = writeln!(self.0, "compend_{name}{labels} {value}");
    }

    fn one(&mut self, name: &str, kind: &str, help: &str, value: f64) {
        self.metric(name, kind, help);
        self.sample(name, &[], value);
    }
}

/// A label value as the text format writes it.
fn escape_label(v: &str) -> String {
    v.replace('\\', "\\\\")
        .replace('"', "\\\"")
        .replace('\n', "\\n")
}

/// The metrics of a fleet's dashboards, from the status.
pub fn prometheus_text(s: &Status) -> String {
    let mut e = Exposition(String::new());
    e.metric(
        "info",
        "gauge",
        "The service's version, rig and model method (value 1).",
    );
    let method = s.model.as_ref().map_or("", |m| m.method.as_str());
    e.sample(
        "info",
        &[("version", &s.version), ("rig", &s.rig), ("method", method)],
        1.0,
    );
    e.one(
        "uptime_seconds",
        "gauge",
        "Seconds since the service started.",
        s.uptime_s,
    );
    e.metric(
        "state",
        "gauge",
        "1 for the service's state, 0 for the others.",
    );
    for st in [
        ServiceState::Idle,
        ServiceState::Calibrating,
        ServiceState::Training,
        ServiceState::Verifying,
        ServiceState::Setup,
        ServiceState::Playing,
        ServiceState::Paused,
        ServiceState::Stopping,
    ] {
        e.sample(
            "state",
            &[("state", st.name())],
            f64::from(u8::from(s.state == st)),
        );
    }
    let f = &s.frames;
    e.one(
        "frames_shown_total",
        "counter",
        "Frames shown since the service started.",
        f.shown_total as f64,
    );
    e.one(
        "frames_dropped_total",
        "counter",
        "Frames dropped since the service started.",
        f.dropped_total as f64,
    );
    e.metric(
        "playback_frames",
        "gauge",
        "Frame counts of the current (or last) playback, by what happened to them.",
    );
    for (what, n) in [
        ("refreshes", f.refreshes),
        ("shown", f.shown),
        ("held", f.held),
        ("dropped_source", f.dropped_source),
        ("dropped_pipeline", f.dropped_pipeline),
    ] {
        e.sample("playback_frames", &[("what", what)], n as f64);
    }
    let m = &s.monitoring;
    e.one(
        "monitoring_checks",
        "gauge",
        "Monitoring checks scored since the model started playing.",
        m.checks as f64,
    );
    e.one(
        "monitoring_unseen_total",
        "counter",
        "Monitoring checks whose frame the camera never saw alone.",
        m.unseen as f64,
    );
    if let Some(p) = m.psnr {
        e.one(
            "monitoring_psnr_db",
            "gauge",
            "PSNR of the last monitoring check against the view it should give, dB.",
            p,
        );
    }
    if let Some(p) = m.baseline_psnr {
        e.one(
            "monitoring_baseline_psnr_db",
            "gauge",
            "The model's first monitoring score, what drift is measured against, dB.",
            p,
        );
    }
    e.one(
        "drift",
        "gauge",
        "1 while the last checks are past the drift threshold.",
        f64::from(u8::from(m.drift)),
    );
    e.one(
        "drift_events_total",
        "counter",
        "Drift detections since the service started.",
        m.drifts as f64,
    );
    e.one(
        "calibrations_total",
        "counter",
        "Calibrations finished (installed or not) since the service started.",
        s.calibrations as f64,
    );
    if let Some(c) = &s.last_calibration {
        e.one(
            "last_calibration_installed",
            "gauge",
            "1 if the last calibration's model was installed.",
            f64::from(u8::from(c.installed)),
        );
    }
    if let Some(v) = s.model.as_ref().and_then(|m| m.verification.as_ref()) {
        e.metric(
            "model_verification_psnr_db",
            "gauge",
            "The served model's verification: test images compensated and as they are, dB.",
        );
        e.sample(
            "model_verification_psnr_db",
            &[("projection", "compensated")],
            v.psnr,
        );
        e.sample(
            "model_verification_psnr_db",
            &[("projection", "uncompensated")],
            v.uncompensated_psnr,
        );
    }
    if let Some(media) = &s.media {
        e.one(
            "media_reconnects_total",
            "counter",
            "Times the playing stream or screen was reconnected.",
            media.reconnects as f64,
        );
        e.one(
            "media_warnings_total",
            "counter",
            "Warnings of the playing media.",
            media.warnings as f64,
        );
    }
    e.0
}

#[cfg(test)]
mod tests {
    use super::*;
    use axum::body::Body;
    use tower::ServiceExt;

    fn console(allow: &[&str], token: Option<&str>) -> (Arc<Console>, tempfile::TempDir) {
        let dir = tempfile::tempdir().unwrap();
        let token_file = token.map(|t| {
            let p = dir.path().join("token");
            std::fs::write(&p, t).unwrap();
            std::fs::set_permissions(&p, std::os::unix::fs::PermissionsExt::from_mode(0o600))
                .unwrap();
            p
        });
        let cfg = HttpConfig {
            listen: None,
            token_file,
            allow: allow.iter().map(|a| a.parse().unwrap()).collect(),
            tls: None,
        };
        let (tx, _rx) = std::sync::mpsc::channel();
        let shared = Arc::new(Shared::new("virtual:test".into(), tx));
        (Arc::new(Console::new(&cfg, shared).unwrap()), dir)
    }

    /// `req` as if sent from `peer`: its status, and its body as text.
    async fn send(c: &Arc<Console>, peer: &str, req: axum::http::Request<Body>) -> (u16, String) {
        let mut req = req;
        req.extensions_mut()
            .insert(ConnectInfo(Peer(peer.parse().unwrap())));
        let r = router(c.clone()).oneshot(req).await.unwrap();
        let code = r.status().as_u16();
        let body = axum::body::to_bytes(r.into_body(), 1 << 20).await.unwrap();
        (code, String::from_utf8_lossy(&body).into_owned())
    }

    fn get(path: &str) -> axum::http::Request<Body> {
        axum::http::Request::get(path)
            .header(header::HOST, "console:7421")
            .body(Body::empty())
            .unwrap()
    }

    fn post(path: &str) -> axum::http::request::Builder {
        axum::http::Request::post(path)
            .header(header::HOST, "console:7421")
            .header(header::CONTENT_TYPE, "application/json")
    }

    const TOKEN: &str = "0123456789abcdef0123";
    const STATUS: &str = r#"{"cmd":"status"}"#;

    #[tokio::test]
    async fn loopback_may_do_everything_and_others_need_the_allow_list_and_the_token() {
        let (c, _d) = console(&["10.0.0.0/24"], Some(TOKEN));
        let (code, body) = send(&c, "127.0.0.1:5000", get("/api/status")).await;
        assert_eq!(code, 200, "{body}");
        assert!(body.contains("\"state\":\"idle\""), "{body}");
        // Not in the allow list: refused whatever it carries.
        let (code, body) = send(&c, "192.168.1.9:5000", get("/api/status")).await;
        assert_eq!(code, 403, "{body}");
        // In it: the token is asked for; the wrong one refused, the right one taken.
        let (code, _) = send(&c, "10.0.0.5:5000", get("/api/status")).await;
        assert_eq!(code, 401);
        let wrong = axum::http::Request::get("/api/status")
            .header(header::AUTHORIZATION, "Bearer nope")
            .body(Body::empty())
            .unwrap();
        assert_eq!(send(&c, "10.0.0.5:5000", wrong).await.0, 401);
        let right = axum::http::Request::get("/api/status")
            .header(header::AUTHORIZATION, format!("Bearer {TOKEN}"))
            .body(Body::empty())
            .unwrap();
        assert_eq!(send(&c, "10.0.0.5:5000", right).await.0, 200);
        // The page sends a browser to the login form, which sets the cookie.
        let (code, _) = send(&c, "10.0.0.5:5000", get("/")).await;
        assert_eq!(code, 303);
        let login = axum::http::Request::post("/login")
            .header(header::CONTENT_TYPE, "application/x-www-form-urlencoded")
            .body(Body::from(format!("token={TOKEN}")))
            .unwrap();
        let mut login = login;
        login
            .extensions_mut()
            .insert(ConnectInfo(Peer("10.0.0.5:5000".parse().unwrap())));
        let r = router(c.clone()).oneshot(login).await.unwrap();
        let cookie = r.headers()[header::SET_COOKIE]
            .to_str()
            .unwrap()
            .to_string();
        assert!(cookie.contains("HttpOnly") && cookie.contains("SameSite=Strict"));
        let with_cookie = axum::http::Request::get("/api/status")
            .header(header::COOKIE, cookie.split(';').next().unwrap())
            .body(Body::empty())
            .unwrap();
        assert_eq!(send(&c, "10.0.0.5:5000", with_cookie).await.0, 200);
    }

    #[tokio::test]
    async fn a_post_needs_the_header_and_this_hosts_origin() {
        let (c, _d) = console(&[], None);
        let peer = "127.0.0.1:5000";
        let plain = post("/api/request").body(Body::from(STATUS)).unwrap();
        let (code, body) = send(&c, peer, plain).await;
        assert_eq!(code, 403, "{body}");
        assert!(body.contains("X-Compend"), "{body}");
        let foreign = post("/api/request")
            .header("x-compend", "1")
            .header(header::ORIGIN, "http://evil.example")
            .body(Body::from(STATUS))
            .unwrap();
        let (code, body) = send(&c, peer, foreign).await;
        assert_eq!(code, 403, "{body}");
        let own = post("/api/request")
            .header("x-compend", "1")
            .header(header::ORIGIN, "http://console:7421")
            .body(Body::from(STATUS))
            .unwrap();
        let (code, body) = send(&c, peer, own).await;
        assert_eq!(code, 200, "{body}");
        assert!(body.contains("\"ok\":true"), "{body}");
        // A malformed request is a 400 with the socket's words.
        let bad = post("/api/request")
            .header("x-compend", "1")
            .body(Body::from("{\"cmd\":\"dance\"}"))
            .unwrap();
        let (code, body) = send(&c, peer, bad).await;
        assert_eq!(code, 400, "{body}");
        assert!(body.contains("expected a JSON object"), "{body}");
        // A body past the cap is refused before it is read whole.
        let huge = post("/api/request")
            .header("x-compend", "1")
            .body(Body::from(vec![b' '; MAX_REQUEST_BYTES + 1]))
            .unwrap();
        assert_eq!(send(&c, peer, huge).await.0, 413);
    }

    #[tokio::test]
    async fn the_page_and_the_metrics_are_served() {
        let (c, _d) = console(&[], None);
        let (code, body) = send(&c, "[::1]:5000", get("/")).await;
        assert_eq!(code, 200);
        assert!(body.contains("<title>compend console</title>"));
        let (code, body) = send(&c, "127.0.0.1:5000", get("/metrics")).await;
        assert_eq!(code, 200);
        let lines = body.lines().map(|l| Ok(l.to_string()));
        let scrape = prometheus_parse::Scrape::parse(lines).unwrap();
        let state = scrape
            .samples
            .iter()
            .find(|s| s.metric == "compend_state" && s.labels.get("state") == Some("idle"))
            .unwrap();
        assert_eq!(state.value, prometheus_parse::Value::Gauge(1.0));
        // No camera frame yet: said, not an empty image.
        let (code, body) = send(&c, "127.0.0.1:5000", get("/api/camera.jpg")).await;
        assert_eq!(code, 404, "{body}");
        c.shared
            .views
            .offer_camera(&crate::raster::CamImage::filled(8, 6, [0.2, 0.4, 0.6]));
        let (code, _) = send(&c, "127.0.0.1:5000", get("/api/camera.jpg")).await;
        assert_eq!(code, 200);
    }

    #[test]
    fn label_values_are_escaped() {
        assert_eq!(escape_label("a\"b\\c\nd"), "a\\\"b\\\\c\\nd");
    }
}
