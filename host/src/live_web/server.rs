//! The live page's HTTP server ([`tiny_http`]): `GET /` the page (HTML, script and style in
//! one, embedded in the binary: no CDN, nothing fetched from elsewhere), `GET /events` the state
//! as server-sent events (`text/event-stream`, one `data:` line of JSON per event, at most every
//! [`EVENT_INTERVAL`] and only when the state changed, a comment line each second otherwise),
//! `GET /state` the latest state once (JSON; with `?poll=1` the page reads it ten times a second
//! instead of the stream, for headless browsers and proxies that hold streams back). Anything but GET is refused (405): the page only
//! reads. Bound to a loopback address, anyone on this computer may read it; bound to another
//! address, every request must carry `?token=` with the random token the server was started
//! with (printed with the URL), else 403.
//!
//! The event stream is written on the request's connection (`Request::into_writer`) after a
//! fixed response head, because tiny_http's own responses buffer a body of unknown length in 8 kB
//! chunks, which would hold events back. Each page's stream runs on its own thread, which reads
//! the [`Board`] (cloning an `Arc` under the lock) and never touches the recorder.
use std::io::Write;
use std::net::SocketAddr;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

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

/// A running server; dropping it stops it (the streams end at their next event).
pub struct LiveServer {
    addr: SocketAddr,
    token: Option<String>,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
}

impl LiveServer {
    /// Listen on `addr` (port 0: any free port) and serve `board`. A non-loopback address gets
    /// a random token (128 bits, hex).
    pub fn start(addr: SocketAddr, board: Board) -> Result<LiveServer> {
        let server = tiny_http::Server::http(addr).map_err(|e| Error::WebServer {
            addr: addr.to_string(),
            message: e.to_string(),
        })?;
        let bound = server
            .server_addr()
            .to_ip()
            .ok_or_else(|| Error::WebServer {
                addr: addr.to_string(),
                message: "not an IP address".into(),
            })?;
        let token = (!addr.ip().is_loopback()).then(|| format!("{:032x}", rand::random::<u128>()));
        let stop = Arc::new(AtomicBool::new(false));
        let thread = {
            let (stop, token) = (stop.clone(), token.clone());
            std::thread::Builder::new()
                .name("jdbb-web".into())
                .spawn(move || serve(server, board, token, stop))
                .map_err(|e| Error::WebServer {
                    addr: addr.to_string(),
                    message: e.to_string(),
                })?
        };
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

    /// The page's URL, with the token when one is needed.
    pub fn url(&self) -> String {
        match &self.token {
            Some(t) => format!("http://{}/?token={t}", self.addr),
            None => format!("http://{}/", self.addr),
        }
    }
}

impl Drop for LiveServer {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

fn header(k: &str, v: &str) -> tiny_http::Header {
    // The names and values here are fixed ASCII.
    tiny_http::Header::from_bytes(k.as_bytes(), v.as_bytes()).expect("ASCII header")
}

fn text(code: u16, body: &str) -> tiny_http::Response<std::io::Cursor<Vec<u8>>> {
    tiny_http::Response::from_string(body)
        .with_status_code(code)
        .with_header(header("Content-Type", "text/plain; charset=utf-8"))
}

/// Answer requests until `stop`.
fn serve(server: tiny_http::Server, board: Board, token: Option<String>, stop: Arc<AtomicBool>) {
    let streams = Arc::new(AtomicUsize::new(0));
    while !stop.load(Ordering::SeqCst) {
        let req = match server.recv_timeout(Duration::from_millis(100)) {
            Ok(Some(r)) => r,
            Ok(None) => continue,
            Err(_) => break,
        };
        // A client that went away while being answered is no error of the server.
        let _ = answer(req, &board, token.as_deref(), &stop, &streams);
    }
}

fn answer(
    req: tiny_http::Request,
    board: &Board,
    token: Option<&str>,
    stop: &Arc<AtomicBool>,
    streams: &Arc<AtomicUsize>,
) -> std::io::Result<()> {
    if *req.method() != tiny_http::Method::Get {
        return req.respond(
            text(405, "the live page only reads: GET only\n").with_header(header("Allow", "GET")),
        );
    }
    if !authorised(req.url(), token) {
        return req.respond(text(
            403,
            "this page needs the token jdbb printed with its URL: add ?token=...\n",
        ));
    }
    let path = req.url().split('?').next().unwrap_or("/").to_string();
    match path.as_str() {
        "/" | "/index.html" => req.respond(
            tiny_http::Response::from_string(page())
                .with_header(header("Content-Type", "text/html; charset=utf-8"))
                .with_header(header("Cache-Control", "no-store")),
        ),
        "/state" => {
            let json = board.lock().unwrap_or_else(|p| p.into_inner()).json.clone();
            req.respond(
                tiny_http::Response::from_string(json.as_str())
                    .with_header(header("Content-Type", "application/json"))
                    .with_header(header("Cache-Control", "no-store")),
            )
        }
        "/events" => {
            if streams.fetch_add(1, Ordering::SeqCst) >= MAX_STREAMS {
                streams.fetch_sub(1, Ordering::SeqCst);
                return req.respond(text(503, "too many pages open; close one\n"));
            }
            let (board, stop, streams) = (board.clone(), stop.clone(), streams.clone());
            let spawned = std::thread::Builder::new()
                .name("jdbb-web-events".into())
                .spawn(move || {
                    let _ = stream_events(req.into_writer(), &board, &stop);
                    streams.fetch_sub(1, Ordering::SeqCst);
                });
            spawned.map(|_| ())
        }
        _ => req.respond(text(404, "not found: the live page is at /\n")),
    }
}

/// Write the event stream until the client goes away or the server stops.
fn stream_events(
    mut w: Box<dyn Write + Send>,
    board: &Board,
    stop: &AtomicBool,
) -> std::io::Result<()> {
    w.write_all(
        b"HTTP/1.1 200 OK\r\nContent-Type: text/event-stream\r\nCache-Control: no-store\r\nConnection: close\r\n\r\nretry: 1000\n\n",
    )?;
    w.flush()?;
    let mut sent = None;
    let mut last_write = Instant::now();
    while !stop.load(Ordering::SeqCst) {
        let (version, json) = {
            let b = board.lock().unwrap_or_else(|p| p.into_inner());
            (b.version, b.json.clone())
        };
        if sent != Some(version) {
            sent = Some(version);
            w.write_all(b"data: ")?;
            w.write_all(json.as_bytes())?;
            w.write_all(b"\n\n")?;
            w.flush()?;
            last_write = Instant::now();
        } else if last_write.elapsed() >= Duration::from_secs(1) {
            // A comment: keeps proxies from closing, and finds a closed page.
            w.write_all(b": idle\n\n")?;
            w.flush()?;
            last_write = Instant::now();
        }
        std::thread::sleep(EVENT_INTERVAL);
    }
    Ok(())
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
