//! The live page's HTTP server, on [`axum`] (hyper and tokio: the maintained mainstream of the Rust
//! ecosystem, in place of the unmaintained tiny_http; docs/live.md): `GET /` the page (HTML, script
//! and style in one, embedded in the binary: no CDN, nothing fetched from elsewhere), `GET /events`
//! the state as server-sent events (`text/event-stream`: `retry: 1000` first, then one `data:` line
//! of JSON per event, looked for every [`EVENT_INTERVAL`] and sent only when the state changed, a
//! comment line after each second without one), `GET /state` the latest state once (JSON; with
//! `?poll=1` the page reads it ten times a second instead of the stream, for headless browsers and
//! proxies that hold streams back). Anything but GET is refused (405): the page only reads. Bound
//! to a loopback address, anyone on this computer may read it; bound to another address, every
//! request must carry `?token=` with the random token the server was started with (printed with the
//! URL), else 403 and the connection closed. Bound to a loopback address, a request must name the
//! server as this computer in its `Host` (`localhost`, `127.0.0.1` or `[::1]`, any port), else
//! 421 and the connection closed: a web page elsewhere that renames itself to 127.0.0.1 (DNS
//! rebinding) cannot read the state.
//!
//! What a client may hold is bounded ([`Limits`], issue 28): at most
//! [`Limits::max_connections`] connections (one more is closed as soon as it is accepted, the
//! others keep working); a request's head must arrive within [`Limits::head_timeout`] of the
//! connection's start or its last answer (hyper's header-read timeout: a client that trickles
//! its head, or a keep-alive connection left idle, is closed); an answer that the client does not
//! read for [`Limits::send_timeout`] closes the connection (a client that pipelines requests
//! without reading cannot make the server hold more than one answer and hyper's buffer of
//! [`MAX_BUF`] for it). Each connection is served by hyper's HTTP/1 builder; no HTTP is written
//! here.
//!
//! The server runs on a thread of its own with its own single-threaded tokio runtime: the
//! recorder never waits for it. The handlers read the [`Board`] by cloning an `Arc` under its
//! lock, never holding the lock across an `.await`. A page that stops reading leaves its
//! connection's task waiting for the socket (hyper stops polling the stream once its buffer is
//! full) until [`Limits::send_timeout`]: it costs no thread, no board read and no sample.
//! Dropping the [`LiveServer`] stops it gracefully: no new connection, the event streams end
//! within [`EVENT_INTERVAL`], the thread is joined; a connection still not done after
//! [`SHUTDOWN_LIMIT`] (a page that stopped reading) is dropped.
use std::convert::Infallible;
use std::future::Future;
use std::net::SocketAddr;
use std::pin::Pin;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Arc;
use std::task::{Context, Poll};
use std::thread::JoinHandle;
use std::time::Duration;

use axum::body::Bytes;
use axum::extract::{Request, State};
use axum::http::header::{ALLOW, CACHE_CONTROL, CONNECTION, CONTENT_TYPE, HOST};
use axum::http::{Method, StatusCode};
use axum::middleware::{self, Next};
use axum::response::sse::{Event, KeepAlive, Sse};
use axum::response::{Html, IntoResponse, Response};
use axum::routing::get;
use axum::Router;
use futures_util::stream::{self, Stream, StreamExt};
use hyper_util::rt::{TokioIo, TokioTimer};
use hyper_util::service::TowerToHyperService;
use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tokio::sync::{watch, Semaphore};

use super::feed::Board;
use crate::{Error, Result};

/// The default address: this computer only.
pub const DEFAULT_ADDR: &str = "127.0.0.1:8765";

/// How often a stream looks for a new state: an event goes out within this of a publication
/// ([`super::feed::PUBLISH_INTERVAL`]).
pub const EVENT_INTERVAL: Duration = Duration::from_millis(20);

/// How long a session's end waits before it stops the server, so that the open pages receive
/// the last state (they keep showing it after the server is gone).
pub const LAST_STATE_GRACE: Duration = Duration::from_millis(250);

/// Most pages streaming at once; more get 503.
pub const MAX_STREAMS: usize = 16;

/// The longest a stopping server waits for its connections to finish (a page that stopped
/// reading never does); then they are dropped.
pub const SHUTDOWN_LIMIT: Duration = Duration::from_secs(1);

/// Most connections open at once, by default ([`Limits`]): four times [`MAX_STREAMS`], room for
/// the pages' streams, their `/state` polls and page loads.
pub const MAX_CONNECTIONS: usize = 64;

/// How long a request's head may take by default ([`Limits::head_timeout`]).
pub const HEAD_TIMEOUT: Duration = Duration::from_secs(10);

/// How long an answer may wait for its client to read by default ([`Limits::send_timeout`]).
pub const SEND_TIMEOUT: Duration = Duration::from_secs(20);

/// hyper's buffer for one connection, each way (its default is about 400 KiB): a request's head
/// must fit (else 431), and a client that does not read holds at most this besides the answer.
pub const MAX_BUF: usize = 64 * 1024;

/// What clients may hold of the server (module docs); [`Limits::default`] is what `--web` uses.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Limits {
    /// Most connections open at once; one more is closed as soon as it is accepted. A
    /// connection that sends no request, or none with the token, counts until it is closed.
    pub max_connections: usize,
    /// The longest a connection may take to send a request's whole head, counted from when it
    /// was accepted or its last answer was sent: a client that trickles its head (slowloris), and
    /// a keep-alive connection left idle, are closed after it.
    pub head_timeout: Duration,
    /// The longest an answer may wait for its client to read any of it: a client that stops
    /// reading (a stalled page, or requests pipelined without reading the answers) is closed
    /// after it.
    pub send_timeout: Duration,
}

impl Default for Limits {
    fn default() -> Limits {
        Limits {
            max_connections: MAX_CONNECTIONS,
            head_timeout: HEAD_TIMEOUT,
            send_timeout: SEND_TIMEOUT,
        }
    }
}

/// An event stream sends a comment after this long without an event: it keeps proxies from
/// closing the stream and finds a closed page.
const KEEP_ALIVE: Duration = Duration::from_secs(1);

/// The page: HTML with its script and style put in ([`page`]).
const PAGE_HTML: &str = include_str!("page/index.html");
const PAGE_JS: &str = include_str!("page/app.js");
const PAGE_CSS: &str = include_str!("page/style.css");

/// The self-contained page: the HTML with the script and the style in it.
pub fn page() -> String {
    PAGE_HTML
        .replace("/*STYLE*/", PAGE_CSS)
        .replace("/*SCRIPT*/", PAGE_JS)
}

/// Whether a request for `url` may be answered: always without a token, else only when its
/// query has `token=` equal to it.
pub fn authorised(url: &str, token: Option<&str>) -> bool {
    let Some(token) = token else {
        return true;
    };
    let query = url.split_once('?').map_or("", |(_, q)| q);
    query
        .split('&')
        .filter_map(|kv| kv.split_once('='))
        .any(|(k, v)| k == "token" && constant_time_eq(v.as_bytes(), token.as_bytes()))
}

/// Compare without stopping at the first difference (the time says nothing of the token).
fn constant_time_eq(a: &[u8], b: &[u8]) -> bool {
    a.len() == b.len() && a.iter().zip(b).fold(0u8, |acc, (x, y)| acc | (x ^ y)) == 0
}

/// The host names a server bound to the loopback address `bound` answers to: `localhost`,
/// `127.0.0.1`, `[::1]` and the bound address itself.
fn local_names(bound: SocketAddr) -> Vec<String> {
    let own = match bound {
        SocketAddr::V4(a) => a.ip().to_string(),
        SocketAddr::V6(a) => format!("[{}]", a.ip()),
    };
    let mut names: Vec<String> = ["localhost", "127.0.0.1", "[::1]"]
        .iter()
        .map(|n| n.to_string())
        .collect();
    if !names.contains(&own) {
        names.push(own);
    }
    names
}

/// Whether a request's `Host` (none: `None`) is one of `names` (case-insensitive), with or
/// without a port. Any port: the name is what a rebinding page cannot fake (its own name is
/// sent), and a port forwarded to this one (an SSH tunnel, `localhost:9000`) is still this
/// computer.
fn host_allowed(host: Option<&[u8]>, names: &[String]) -> bool {
    let Some(host) = host else {
        return false;
    };
    let name_end = match host.first() {
        Some(b'[') => host.iter().position(|&b| b == b']').map(|i| i + 1),
        _ => Some(host.iter().position(|&b| b == b':').unwrap_or(host.len())),
    };
    let Some(name_end) = name_end else {
        return false;
    };
    let (name, port) = host.split_at(name_end);
    let port_ok = match port.split_first() {
        None => true,
        Some((b':', digits)) => !digits.is_empty() && digits.iter().all(u8::is_ascii_digit),
        Some(_) => false,
    };
    port_ok
        && names
            .iter()
            .any(|n| n.as_bytes().eq_ignore_ascii_case(name))
}

/// A running server; dropping it stops it (module docs).
pub struct LiveServer {
    addr: SocketAddr,
    token: Option<String>,
    stop: watch::Sender<bool>,
    thread: Option<JoinHandle<()>>,
}

impl LiveServer {
    /// Listen on `addr` (port 0: any free port) and serve `board`. A non-loopback address gets
    /// a random token (128 bits, hex).
    pub fn start(addr: SocketAddr, board: Board) -> Result<LiveServer> {
        LiveServer::start_with(addr, board, Limits::default())
    }

    /// [`LiveServer::start`] with other [`Limits`] (a test's short timeouts).
    pub fn start_with(addr: SocketAddr, board: Board, limits: Limits) -> Result<LiveServer> {
        let failed = |e: std::io::Error| Error::WebServer {
            addr: addr.to_string(),
            message: e.to_string(),
        };
        // Bound here, so that an address in use is said before anything else starts.
        let std_listener = std::net::TcpListener::bind(addr).map_err(failed)?;
        std_listener.set_nonblocking(true).map_err(failed)?;
        let bound = std_listener.local_addr().map_err(failed)?;
        let runtime = tokio::runtime::Builder::new_current_thread()
            .enable_io()
            .enable_time()
            .build()
            .map_err(failed)?;
        let listener = {
            let _in_runtime = runtime.enter();
            tokio::net::TcpListener::from_std(std_listener).map_err(failed)?
        };
        let token = (!addr.ip().is_loopback()).then(|| format!("{:032x}", rand::random::<u128>()));
        let (stop, stopped) = watch::channel(false);
        let shared = Shared {
            board,
            token: token.clone(),
            hosts: token.is_none().then(|| local_names(bound)),
            bound,
            page: Bytes::from(page()),
            streams: Arc::new(AtomicUsize::new(0)),
            stopped: stopped.clone(),
        };
        let thread = std::thread::Builder::new()
            .name("jdbb-web".into())
            .spawn(move || serve(runtime, listener, router(shared), limits, stopped))
            .map_err(failed)?;
        Ok(LiveServer {
            addr: bound,
            token,
            stop,
            thread: Some(thread),
        })
    }

    /// The address it listens on (the port chosen when 0 was asked).
    pub fn addr(&self) -> SocketAddr {
        self.addr
    }

    /// The token requests must carry, on a non-loopback address.
    pub fn token(&self) -> Option<&str> {
        self.token.as_deref()
    }

    /// The page's URL, with the token when one is needed. Bound to every address (0.0.0.0,
    /// `::`), which no browser opens, the URL names this computer's address instead
    /// ([`reachable_ip`]); without one, the unspecified address stays and [`Self::url_note`] says
    /// what to put in its place.
    pub fn url(&self) -> String {
        let mut addr = self.addr;
        if addr.ip().is_unspecified() {
            if let Some(ip) = reachable_ip(addr.is_ipv6()) {
                addr.set_ip(ip);
            }
        }
        match &self.token {
            Some(t) => format!("http://{addr}/?token={t}"),
            None => format!("http://{addr}/"),
        }
    }

    /// For a server bound to every address: which addresses the page answers on, or, when this
    /// computer's address is not known, that the URL's address must be replaced by it.
    pub fn url_note(&self) -> Option<String> {
        if !self.addr.ip().is_unspecified() {
            return None;
        }
        Some(match reachable_ip(self.addr.is_ipv6()) {
            Some(ip) => format!(
                "{} listens on every address of this computer; the URL names {ip}, its address on the network (another of its addresses or its name works too)",
                self.addr.ip()
            ),
            None => format!(
                "{} listens on every address of this computer, but none was found to name: open the URL with this computer's IP address or name in place of {}",
                self.addr.ip(),
                self.addr.ip()
            ),
        })
    }
}

/// The address of this computer that its default route leaves from: an address other computers
/// on the network reach it at. A UDP socket "connected" to a documentation address (RFC 5737,
/// RFC 3849) sends nothing; its local address is the answer. None without a route.
fn reachable_ip(v6: bool) -> Option<std::net::IpAddr> {
    let (bind, probe) = if v6 {
        ("[::]:0", "[2001:db8::1]:9")
    } else {
        ("0.0.0.0:0", "192.0.2.1:9")
    };
    let socket = std::net::UdpSocket::bind(bind).ok()?;
    socket.connect(probe).ok()?;
    let ip = socket.local_addr().ok()?.ip();
    (!ip.is_unspecified() && !ip.is_loopback()).then_some(ip)
}

impl Drop for LiveServer {
    fn drop(&mut self) {
        self.stop.send_replace(true);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// What every handler reads.
#[derive(Clone)]
struct Shared {
    board: Board,
    token: Option<String>,
    /// On a loopback address, the host names answered to ([`local_names`]).
    hosts: Option<Vec<String>>,
    /// The address listened on.
    bound: SocketAddr,
    /// The page, made once.
    page: Bytes,
    /// Event streams open now.
    streams: Arc<AtomicUsize>,
    /// Becomes true when the server stops.
    stopped: watch::Receiver<bool>,
}

/// Run the server on this thread until `stopped`, then stop it gracefully, dropping what is
/// still open after [`SHUTDOWN_LIMIT`] (with the runtime).
///
/// Each accepted connection takes one of `limits.max_connections` permits, or is closed at once
/// when none is left; it is served by hyper's HTTP/1 builder with the head timeout and
/// [`MAX_BUF`], over a socket whose writes fail after `limits.send_timeout` without progress
/// ([`SendLimit`]). Stopping waits until every permit is back: every connection closed.
fn serve(
    runtime: tokio::runtime::Runtime,
    listener: tokio::net::TcpListener,
    app: Router,
    limits: Limits,
    mut stopped: watch::Receiver<bool>,
) {
    // A semaphore counts at most u32::MAX permits at once for `acquire_many`.
    let cap = limits.max_connections.clamp(1, u32::MAX as usize >> 1);
    let mut http = hyper::server::conn::http1::Builder::new();
    http.timer(TokioTimer::new())
        .header_read_timeout(limits.head_timeout)
        .max_buf_size(MAX_BUF);
    runtime.block_on(async move {
        let permits = Arc::new(Semaphore::new(cap));
        loop {
            let accepted = tokio::select! {
                a = listener.accept() => a,
                // An error: the LiveServer is gone, which also means stop.
                _ = stopped.wait_for(|s| *s) => break,
            };
            let tcp = match accepted {
                Ok((tcp, _)) => tcp,
                // Out of file descriptors, or the connection gone before it was accepted: wait
                // a little rather than spin.
                Err(_) => {
                    tokio::time::sleep(EVENT_INTERVAL).await;
                    continue;
                }
            };
            let Ok(permit) = permits.clone().try_acquire_owned() else {
                // Over the cap: closed at once, before anything is read.
                drop(tcp);
                continue;
            };
            let _ = tcp.set_nodelay(true);
            let io = TokioIo::new(SendLimit::new(tcp, limits.send_timeout));
            let conn = http.serve_connection(io, TowerToHyperService::new(app.clone()));
            let mut stop = stopped.clone();
            tokio::spawn(async move {
                let mut conn = std::pin::pin!(conn);
                let stopping = tokio::select! {
                    _ = conn.as_mut() => false,
                    _ = stop.wait_for(|s| *s) => true,
                };
                if stopping {
                    // Idle connections close now, an answer under way is finished.
                    conn.as_mut().graceful_shutdown();
                    let _ = conn.await;
                }
                drop(permit);
            });
        }
        drop(listener);
        let _ = tokio::time::timeout(SHUTDOWN_LIMIT, permits.acquire_many(cap as u32)).await;
    });
}

/// A connection's socket whose writes fail (`TimedOut`) once one has waited `limit` for the
/// client to read: hyper then drops the connection.
struct SendLimit {
    tcp: tokio::net::TcpStream,
    limit: Duration,
    /// Running while a write waits for the client.
    stalled: Option<Pin<Box<tokio::time::Sleep>>>,
}

impl SendLimit {
    fn new(tcp: tokio::net::TcpStream, limit: Duration) -> SendLimit {
        SendLimit {
            tcp,
            limit,
            stalled: None,
        }
    }

    /// What a write that returned `poll` gives: progress stops the clock, waiting starts it (or
    /// fails once it has run out).
    fn watch<T>(
        &mut self,
        poll: Poll<std::io::Result<T>>,
        cx: &mut Context<'_>,
    ) -> Poll<std::io::Result<T>> {
        if poll.is_ready() {
            self.stalled = None;
            return poll;
        }
        let limit = self.limit;
        let clock = self
            .stalled
            .get_or_insert_with(|| Box::pin(tokio::time::sleep(limit)));
        match clock.as_mut().poll(cx) {
            Poll::Ready(()) => Poll::Ready(Err(std::io::Error::new(
                std::io::ErrorKind::TimedOut,
                "the client read nothing of its answer for the send timeout",
            ))),
            Poll::Pending => Poll::Pending,
        }
    }
}

impl AsyncRead for SendLimit {
    fn poll_read(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<std::io::Result<()>> {
        Pin::new(&mut self.tcp).poll_read(cx, buf)
    }
}

impl AsyncWrite for SendLimit {
    fn poll_write(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &[u8],
    ) -> Poll<std::io::Result<usize>> {
        let poll = Pin::new(&mut self.tcp).poll_write(cx, buf);
        self.watch(poll, cx)
    }

    fn poll_write_vectored(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        bufs: &[std::io::IoSlice<'_>],
    ) -> Poll<std::io::Result<usize>> {
        let poll = Pin::new(&mut self.tcp).poll_write_vectored(cx, bufs);
        self.watch(poll, cx)
    }

    fn is_write_vectored(&self) -> bool {
        self.tcp.is_write_vectored()
    }

    fn poll_flush(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        let poll = Pin::new(&mut self.tcp).poll_flush(cx);
        self.watch(poll, cx)
    }

    fn poll_shutdown(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        let poll = Pin::new(&mut self.tcp).poll_shutdown(cx);
        self.watch(poll, cx)
    }
}

/// The routes, behind the rules that hold for every request ([`guard`]).
fn router(shared: Shared) -> Router {
    Router::new()
        .route("/", get(index))
        .route("/index.html", get(index))
        .route("/state", get(state))
        .route("/events", get(events))
        .fallback(not_found)
        .layer(middleware::from_fn_with_state(shared.clone(), guard))
        .with_state(shared)
}

/// GET only (405 otherwise); on a loopback address a `Host` naming this computer (421
/// without), on another the token (403 without): both refusals close the connection, so that
/// nothing is held for a client that may not read.
async fn guard(State(shared): State<Shared>, req: Request, next: Next) -> Response {
    if req.method() != Method::GET {
        return (
            StatusCode::METHOD_NOT_ALLOWED,
            [(ALLOW, "GET")],
            "the live page only reads: GET only\n",
        )
            .into_response();
    }
    if let Some(hosts) = &shared.hosts {
        let host = req.headers().get(HOST).map(|h| h.as_bytes());
        if !host_allowed(host, hosts) {
            let text = format!(
                "this page answers only as this computer: open http://127.0.0.1:{}/\n",
                shared.bound.port()
            );
            return (
                StatusCode::MISDIRECTED_REQUEST,
                [(CONNECTION, "close")],
                text,
            )
                .into_response();
        }
    }
    let url = req.uri().path_and_query().map_or("/", |pq| pq.as_str());
    if !authorised(url, shared.token.as_deref()) {
        return (
            StatusCode::FORBIDDEN,
            [(CONNECTION, "close")],
            "this page needs the token jdbb printed with its URL: add ?token=...\n",
        )
            .into_response();
    }
    next.run(req).await
}

async fn index(State(shared): State<Shared>) -> Response {
    ([(CACHE_CONTROL, "no-store")], Html(shared.page.clone())).into_response()
}

/// The board's JSON as a body that shares it (no copy per answer: a client that asks for it
/// many times and reads slowly holds no copies).
struct SharedJson(Arc<String>);

impl AsRef<[u8]> for SharedJson {
    fn as_ref(&self) -> &[u8] {
        self.0.as_bytes()
    }
}

async fn state(State(shared): State<Shared>) -> Response {
    let json = latest(&shared.board).1;
    (
        [
            (CONTENT_TYPE, "application/json"),
            (CACHE_CONTROL, "no-store"),
        ],
        Bytes::from_owner(SharedJson(json)),
    )
        .into_response()
}

async fn not_found() -> Response {
    (StatusCode::NOT_FOUND, "not found: the live page is at /\n").into_response()
}

/// The board's version and JSON (an `Arc` cloned under the lock).
fn latest(board: &Board) -> (u64, Arc<String>) {
    let b = board.lock().unwrap_or_else(|p| p.into_inner());
    (b.version, b.json.clone())
}

async fn events(State(shared): State<Shared>) -> Response {
    let Some(slot) = StreamSlot::take(&shared.streams) else {
        return (
            StatusCode::SERVICE_UNAVAILABLE,
            "too many pages open; close one\n",
        )
            .into_response();
    };
    let sse = Sse::new(event_stream(shared.board, shared.stopped, slot))
        .keep_alive(KeepAlive::new().interval(KEEP_ALIVE).text("idle"));
    // Replaces the no-cache axum sets.
    ([(CACHE_CONTROL, "no-store")], sse).into_response()
}

/// One of the [`MAX_STREAMS`] places of an open event stream, given back when dropped (when the
/// stream ends or its connection closes).
struct StreamSlot(Arc<AtomicUsize>);

impl StreamSlot {
    fn take(streams: &Arc<AtomicUsize>) -> Option<StreamSlot> {
        if streams.fetch_add(1, Ordering::SeqCst) >= MAX_STREAMS {
            streams.fetch_sub(1, Ordering::SeqCst);
            return None;
        }
        Some(StreamSlot(streams.clone()))
    }
}

impl Drop for StreamSlot {
    fn drop(&mut self) {
        self.0.fetch_sub(1, Ordering::SeqCst);
    }
}

/// What an event stream follows.
struct Follow {
    board: Board,
    stopped: watch::Receiver<bool>,
    /// The version last sent.
    sent: Option<u64>,
    _slot: StreamSlot,
}

/// `retry: 1000`, then the board's JSON each time its version changed, looked for every
/// [`EVENT_INTERVAL`], until the server stops.
fn event_stream(
    board: Board,
    stopped: watch::Receiver<bool>,
    slot: StreamSlot,
) -> impl Stream<Item = std::result::Result<Event, Infallible>> + Send + 'static {
    let follow = Follow {
        board,
        stopped,
        sent: None,
        _slot: slot,
    };
    let retry = Event::default().retry(Duration::from_millis(1000));
    stream::once(std::future::ready(Ok(retry))).chain(stream::unfold(follow, |mut f| async move {
        loop {
            if *f.stopped.borrow() {
                return None;
            }
            let (version, json) = latest(&f.board);
            if f.sent != Some(version) {
                f.sent = Some(version);
                return Some((Ok(Event::default().data(json.as_str())), f));
            }
            tokio::time::sleep(EVENT_INTERVAL).await;
        }
    }))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn without_a_token_every_request_is_authorised() {
        assert!(authorised("/", None));
        assert!(authorised("/events?x=1", None));
    }

    #[test]
    fn with_a_token_only_the_exact_token_is_authorised() {
        let t = Some("00ff");
        assert!(authorised("/?token=00ff", t));
        assert!(authorised("/events?a=b&token=00ff", t));
        assert!(!authorised("/", t));
        assert!(!authorised("/?token=", t));
        assert!(!authorised("/?token=00fe", t));
        assert!(!authorised("/?token=00ff0", t));
        assert!(!authorised("/?tokens=00ff", t));
        assert!(!authorised("/00ff", t));
    }

    #[test]
    fn on_loopback_only_this_computer_is_a_host() {
        let names = local_names("127.0.0.1:8765".parse().unwrap());
        let ok = |h: &str| host_allowed(Some(h.as_bytes()), &names);
        for h in [
            "127.0.0.1:8765",
            "localhost:8765",
            "LocalHost:8765",
            "[::1]:8765",
            "localhost",
            "127.0.0.1",
            "localhost:9000",
        ] {
            assert!(ok(h), "{h}");
        }
        for h in [
            "evil.example:8765",
            "evil.example",
            "localhost.evil.example:8765",
            "127.0.0.1.evil.example",
            "127.0.0.1:8765.evil.example",
            "localhost:",
            "localhost:80x",
            "localhost:8765:1",
            "[::1",
            "[::1]x",
            "",
        ] {
            assert!(!ok(h), "{h}");
        }
        assert!(!host_allowed(None, &names));
        // The bound address itself.
        let own = local_names("127.0.0.2:80".parse().unwrap());
        for h in ["127.0.0.2:80", "127.0.0.2", "localhost", "[::1]"] {
            assert!(host_allowed(Some(h.as_bytes()), &own), "{h}");
        }
        let v6 = local_names("[::1]:9000".parse().unwrap());
        assert_eq!(v6.len(), 3);
        assert!(host_allowed(Some(b"[::1]:9000"), &v6));
        assert!(!host_allowed(Some(b"::1:9000"), &v6));
    }

    #[test]
    fn the_page_is_self_contained() {
        let p = page();
        assert!(p.contains("<script>") && p.contains("EventSource"));
        assert!(!p.contains("/*SCRIPT*/") && !p.contains("/*STYLE*/"));
        // Nothing from elsewhere: no src= or href= at all, no import, no fetch of another URL
        // (the one http:// is the SVG namespace's name).
        for bad in ["src=", "href=", "import ", "url("] {
            assert!(!p.contains(bad), "{bad}");
        }
        assert_eq!(p.matches("http://").count(), 1);
        assert!(p.contains("\"http://www.w3.org/2000/svg\""));
        // The one fetch is of the server's own /state (?poll=1).
        assert_eq!(p.matches("fetch(").count(), 1);
        assert!(p.contains("fetch(state,"));
    }

    #[test]
    fn a_non_local_address_gets_a_token_and_a_local_one_none() {
        let board = super::super::feed::new_board();
        let local = LiveServer::start("127.0.0.1:0".parse().unwrap(), board.clone()).unwrap();
        assert!(local.token().is_none());
        assert!(local.addr().port() != 0);
        assert_eq!(local.url(), format!("http://{}/", local.addr()));
        let any = LiveServer::start("0.0.0.0:0".parse().unwrap(), board).unwrap();
        let t = any.token().unwrap().to_string();
        assert_eq!(t.len(), 32);
        assert!(any.url().ends_with(&format!("?token={t}")));
    }
}
