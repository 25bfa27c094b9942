//! The live page (issue 18) from the outside: the server on an ephemeral port, fed by a synthetic
//! test — D along a real plan at its programmed feed, with a 4 µm once-per-revolution wobble on
//! the arcs — read with a plain TCP client: the page, the event stream (rate of events, progress
//! through every circle, the trace's points and deviation), the read-only and token rules.
#![cfg(unix)] // the feed's CPU time is read with clock_gettime
use std::io::{BufRead, BufReader, Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use jdbb::link::stream::{SeqSample, Stats};
use jdbb::live_web::feed::{new_board, LiveFeed};
use jdbb::live_web::server::{Limits, LiveServer};
use jdbb::plan::build::{plan, PlanSpec};
use jdbb::plan::{Dialect, Plan, Plane, Segment};
use jdbb_core::protocol::{Sample, Status};

fn test_plan() -> Plan {
    let spec = PlanSpec::machine_test(
        &[85.0, 95.0],
        &[0.0],
        Plane::Xy,
        2000.0,
        [10.0, 20.0, 0.0],
        Dialect::Linuxcnc,
    );
    plan(&spec, &jdbb_core::calib::Calibration::DEFAULT).unwrap()
}

/// D at 1 kHz along the plan from its first motion after the operator's stop, at the programmed
/// feed, dwells included; on arcs + 4 µm·cos(angle).
fn synthetic_d(plan: &Plan) -> Vec<f64> {
    let c = plan.centre_mm;
    let dist = |p: [f64; 3]| {
        ((p[0] - c[0]).powi(2) + (p[1] - c[1]).powi(2) + (p[2] - c[2]).powi(2)).sqrt()
    };
    let first = plan
        .segments
        .iter()
        .position(|s| matches!(s, Segment::Stop))
        .unwrap()
        + 1;
    let dt = 1e-3;
    let mut d = vec![];
    let mut here = plan.start_mm;
    // A second at rest before the cycle start.
    d.extend(std::iter::repeat_n(dist(here), 1000));
    for (i, s) in plan.segments.iter().enumerate().skip(first) {
        let Some(dur) = s.nominal_duration_s() else {
            continue;
        };
        let n = (dur / dt).round() as usize;
        for k in 0..n {
            match s {
                Segment::Dwell { .. } => d.push(dist(here)),
                _ => {
                    let p = plan.position_at(i, s.length_mm() * (k as f64 + 0.5) / n as f64);
                    let wobble = if matches!(s, Segment::Arc { .. }) {
                        let a = (p[1] - c[1]).atan2(p[0] - c[0]);
                        4e-3 * a.cos()
                    } else {
                        0.0
                    };
                    d.push(dist(p) + wobble);
                }
            }
        }
        if let Some(to) = s.to_mm() {
            here = to;
        }
    }
    d.extend(std::iter::repeat_n(dist(here), 1000));
    d
}

fn get(addr: SocketAddr, path: &str) -> (u16, String) {
    request(addr, "GET", path)
}

fn request(addr: SocketAddr, method: &str, path: &str) -> (u16, String) {
    let (code, _, body) = exchange(addr, method, path);
    (code, body)
}

/// One request over HTTP/1.0 (the body as it is, never chunked): the status code, the head with
/// the header names lower-cased (HTTP's are case-insensitive), and the body.
fn exchange(addr: SocketAddr, method: &str, path: &str) -> (u16, String, String) {
    let mut s = TcpStream::connect(addr).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
    write!(
        s,
        "{method} {path} HTTP/1.0\r\nHost: {addr}\r\nContent-Length: 0\r\n\r\n"
    )
    .unwrap();
    let mut text = String::new();
    s.read_to_string(&mut text).unwrap();
    let code = text[9..12].parse().unwrap();
    let (head, body) = text.split_once("\r\n\r\n").unwrap_or((&text, ""));
    (code, lower_names(head), body.to_string())
}

/// A response head with its header names lower-cased, each line ending in CRLF.
fn lower_names(head: &str) -> String {
    let mut lines = head.split("\r\n");
    let mut out = format!("{}\r\n", lines.next().unwrap_or(""));
    for line in lines.filter(|l| !l.is_empty()) {
        match line.split_once(':') {
            Some((name, value)) => {
                out.push_str(&format!("{}:{value}\r\n", name.to_ascii_lowercase()))
            }
            None => out.push_str(&format!("{line}\r\n")),
        }
    }
    out
}

/// The body of a `Transfer-Encoding: chunked` response as the bytes it carries.
struct Dechunk<R> {
    inner: R,
    /// Bytes left in the current chunk.
    left: usize,
    done: bool,
}

impl<R: BufRead> Read for Dechunk<R> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        if self.left == 0 {
            if self.done {
                return Ok(0);
            }
            let mut size = String::new();
            if self.inner.read_line(&mut size)? == 0 {
                return Ok(0);
            }
            let hex = size.trim_end().split(';').next().unwrap_or("");
            self.left = usize::from_str_radix(hex, 16).map_err(|e| {
                std::io::Error::new(std::io::ErrorKind::InvalidData, format!("{size:?}: {e}"))
            })?;
            if self.left == 0 {
                self.done = true;
                return Ok(0);
            }
        }
        let most = buf.len().min(self.left);
        let n = self.inner.read(&mut buf[..most])?;
        self.left -= n;
        if self.left == 0 {
            let mut crlf = [0; 2];
            self.inner.read_exact(&mut crlf)?;
            assert_eq!(&crlf, b"\r\n", "a chunk ends with CRLF");
        }
        Ok(n)
    }
}

/// Send a GET for `path` over HTTP/1.1 and read the response's head; returns the head (header
/// names lower-cased: HTTP's are case-insensitive) and a reader of the body (chunks undone).
fn open_stream(addr: SocketAddr, path: &str) -> (String, Box<dyn BufRead>) {
    let mut s = TcpStream::connect(addr).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(2))).unwrap();
    write!(s, "GET {path} HTTP/1.1\r\nHost: {addr}\r\n\r\n").unwrap();
    let mut r = BufReader::new(s);
    let mut raw = String::new();
    loop {
        let mut line = String::new();
        if r.read_line(&mut line).unwrap() == 0 || line == "\r\n" {
            break;
        }
        raw.push_str(&line);
    }
    let head = lower_names(&raw);
    let body: Box<dyn BufRead> = if head.contains("\r\ntransfer-encoding: chunked\r\n") {
        Box::new(BufReader::new(Dechunk {
            inner: r,
            left: 0,
            done: false,
        }))
    } else {
        Box::new(r)
    };
    (head, body)
}

/// Read `data:` events from /events for `for_time`; returns (arrival time, JSON) of each.
fn events(addr: SocketAddr, path: &str, for_time: Duration) -> Vec<(Instant, serde_json::Value)> {
    let (head, mut r) = open_stream(addr, path);
    assert!(head.starts_with("HTTP/1.1 200"), "{head}");
    assert!(
        head.contains("\r\ncontent-type: text/event-stream\r\n"),
        "{head}"
    );
    assert!(head.contains("\r\ncache-control: no-store\r\n"), "{head}");
    let t0 = Instant::now();
    let mut out = vec![];
    while t0.elapsed() < for_time {
        let mut line = String::new();
        if r.read_line(&mut line).unwrap() == 0 {
            break;
        }
        if let Some(json) = line.strip_prefix("data: ") {
            let v: serde_json::Value = serde_json::from_str(json.trim_end()).unwrap();
            let ended = !v["ended"].is_null();
            out.push((Instant::now(), v));
            if ended {
                break;
            }
        }
    }
    out
}

/// Feed `d` (1 kHz device time) in batches of 100 samples, 1 ms apart (100× real time).
fn feed_in_thread(
    mut feed: LiveFeed,
    d: Vec<f64>,
    done: Arc<AtomicBool>,
) -> std::thread::JoinHandle<()> {
    std::thread::spawn(move || {
        let mut stats = Stats::default();
        for (b, chunk) in d.chunks(100).enumerate() {
            let batch: Vec<SeqSample> = chunk
                .iter()
                .enumerate()
                .map(|(i, &d_mm)| {
                    let seq = (b * 100 + i) as u64;
                    SeqSample {
                        seq,
                        sample: Sample {
                            t_us: 1000 * seq,
                            enc1: 0,
                            enc2: 0,
                            d_mm,
                            status: Status(0),
                        },
                    }
                })
                .collect();
            stats.samples += batch.len() as u64;
            feed.samples(&batch);
            feed.publish_if_due(&stats, Instant::now());
            std::thread::sleep(Duration::from_millis(1));
        }
        // The diagnosis of the last circle runs in its own thread: publish until it is there.
        let t0 = Instant::now();
        while feed.circle_diagnoses().len() < 2 && t0.elapsed() < Duration::from_secs(120) {
            std::thread::sleep(Duration::from_millis(50));
            feed.publish_if_due(&stats, Instant::now());
        }
        feed.finish(&stats, "time limit reached");
        done.store(true, Ordering::SeqCst);
    })
}

#[test]
fn the_page_follows_a_synthetic_test_through_every_circle() {
    let plan = test_plan();
    let d = synthetic_d(&plan);
    let n_samples = d.len() as u64;
    let board = new_board();
    let server = LiveServer::start("127.0.0.1:0".parse().unwrap(), board.clone()).unwrap();
    let addr = server.addr();
    println!("live page on {}", server.url());
    assert!(server.token().is_none());

    let (code, page) = get(addr, "/");
    assert_eq!(code, 200);
    assert!(page.contains("EventSource") && page.contains("id=\"progress\""));

    let done = Arc::new(AtomicBool::new(false));
    let feeder = feed_in_thread(
        LiveFeed::new(board.clone(), Some(&plan), Some(20.0)),
        d,
        done.clone(),
    );
    // The whole synthetic test takes about (its samples / 100) ms, then the last circle's
    // diagnosis; read until the end.
    let run = Duration::from_secs(150);
    let evs = events(addr, "/events", run);
    feeder.join().unwrap();
    assert!(done.load(Ordering::SeqCst));

    // The page was kept up to date while the samples came, not told once at the end: many
    // events during the circles (counted, not timed; 25 publications a second are due while the
    // test runs for seconds).
    let during = evs
        .iter()
        .filter(|(_, v)| v["progress"]["phase"] == "circle")
        .count();
    println!("{} events, {during} during the circles", evs.len());
    assert!(during >= 10, "{during} events during the circles");
    // Versions increase; every circle is seen on its arcs, in both senses, with a trace.
    let mut last_version = 0;
    let mut seen = std::collections::BTreeSet::new();
    let mut max_points = 0;
    for (_, v) in &evs {
        let version = v["version"].as_u64().unwrap();
        if version == 0 {
            // The page connected before the first publication: the empty board, which says
            // nothing about progress yet.
            assert_eq!(last_version, 0, "the empty board comes only first");
            assert!(
                v["progress"].is_null(),
                "the empty board has no progress: {v}"
            );
            continue;
        }
        assert!(version > last_version, "versions increase");
        last_version = version;
        let p = &v["progress"];
        assert_eq!(p["circles"], 2);
        if p["phase"] == "circle" {
            seen.insert((
                p["circle"].as_u64().unwrap(),
                p["sense"].as_str().unwrap_or("-").to_string(),
            ));
        }
        if let Some(pts) = v["trace"]["points"].as_array() {
            assert!(pts.len() <= 2000);
            max_points = max_points.max(pts.len());
        }
    }
    let want: std::collections::BTreeSet<_> = [(1, "ccw"), (1, "cw"), (2, "ccw"), (2, "cw")]
        .into_iter()
        .map(|(k, s)| (k, s.to_string()))
        .collect();
    assert!(want.is_subset(&seen), "seen {seen:?}");
    assert!(max_points > 1000, "trace points {max_points}");
    // The end: all done, 100 %, the count of samples, the last circle's trace showing the
    // 4 µm wobble (peak to valley 8 µm, within the decimation and the lead-in's timing).
    let (_, last) = evs.last().unwrap();
    assert_eq!(last["ended"], "time limit reached");
    assert_eq!(last["progress"]["phase"], "done");
    assert_eq!(last["progress"]["percent"], 100.0);
    assert_eq!(last["counts"]["samples"], n_samples);
    let devs: Vec<f64> = last["trace"]["points"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| p["dev_um"].as_f64().unwrap())
        .collect();
    let pv = devs.iter().cloned().fold(f64::MIN, f64::max)
        - devs.iter().cloned().fold(f64::MAX, f64::min);
    println!(
        "last trace: {} points, peak to valley {pv:.3} µm",
        devs.len()
    );
    assert!((pv - 8.0).abs() < 0.2, "peak to valley {pv} µm");
    assert_eq!(last["trace"]["circle"], 2);
    // A point's angle matches its deviation: dev ≈ 4 cos(angle) − mean.
    for p in last["trace"]["points"].as_array().unwrap() {
        let a = p["angle_deg"].as_f64().unwrap().to_radians();
        let dev = p["dev_um"].as_f64().unwrap();
        assert!((dev - 4.0 * a.cos()).abs() < 0.6, "{p}");
    }

    // The diagnosis while recording, circle by circle: circle 1 after its feed-out (nothing
    // before it fixes the feed), circle 2 as soon as its data arcs were in, timed at circle 1's
    // feed (its text says so); each names the 4 µm wobble as a centring error and nothing else,
    // as a table of ranked effects with G per direction and H.
    let list = last["circle_diagnoses"].as_array().unwrap();
    assert_eq!(list.len(), 2, "{list:?}");
    for (k, c) in list.iter().enumerate() {
        let text = c["text"].as_str().unwrap();
        println!("circle {} diagnosed in {} ms:\n{text}", k + 1, c["took_ms"]);
        assert_eq!(c["circle"], k + 1);
        assert!(text.starts_with("synchronised with the plan"), "{text}");
        assert_eq!(c["pass"], true, "{text}");
        assert!(
            text.contains("no machine effect is supported by the data"),
            "{text}"
        );
        let effects = c["effects"].as_array().unwrap();
        let names: Vec<&str> = effects
            .iter()
            .map(|e| e["name"].as_str().unwrap())
            .collect();
        assert_eq!(names, ["setup_offset", "length_offset"], "{text}");
        assert_eq!(effects[0]["step"], "set-up");
        // 4 µm to a nanometre (the synthetic record's segment times are rounded to its 1 ms).
        let value: f64 = effects[0]["value"]
            .as_str()
            .unwrap()
            .split(' ')
            .next()
            .unwrap()
            .parse()
            .unwrap();
        assert!((value - 4.0).abs() < 1e-3, "{text}");
        assert_eq!(effects[0]["unit"], "µm");
        let zones: Vec<&str> = c["zones"]
            .as_array()
            .unwrap()
            .iter()
            .map(|z| z["direction"].as_str().unwrap())
            .collect();
        assert_eq!(zones, ["ccw", "cw"]);
        assert!(!c["h_um"].is_null());
    }
    let note = "circle 2 timed from its feed-in at the feed of the circle before it";
    assert!(!list[0]["text"]
        .as_str()
        .unwrap()
        .contains("timed from its feed-in"));
    assert!(
        list[1]["text"].as_str().unwrap().contains(note),
        "{}",
        list[1]["text"]
    );
    // Every event carries the list as it stood: it only grows.
    let mut shown = 0;
    for (_, v) in &evs {
        let n = v["circle_diagnoses"].as_array().map_or(0, Vec::len);
        assert!(n >= shown, "the list of circle diagnoses shrank");
        shown = n;
    }

    // /state gives the same last state once.
    let (code, body) = get(addr, "/state");
    assert_eq!(code, 200);
    let st: serde_json::Value = serde_json::from_str(&body).unwrap();
    assert_eq!(st["version"], last["version"]);
}

#[test]
fn the_page_only_reads_and_unknown_paths_are_not_found() {
    let server = LiveServer::start("127.0.0.1:0".parse().unwrap(), new_board()).unwrap();
    let addr = server.addr();
    for m in ["POST", "PUT", "DELETE", "HEAD"] {
        for path in ["/", "/events", "/nothing"] {
            let (code, head, body) = exchange(addr, m, path);
            assert_eq!(code, 405, "{m} {path}: {body}");
            assert!(head.contains("\r\nallow: GET\r\n"), "{m} {path}: {head}");
            if m != "HEAD" {
                assert_eq!(body, "the live page only reads: GET only\n");
            }
        }
    }
    let (code, head, body) = exchange(addr, "GET", "/nothing?x=1");
    assert_eq!(code, 404);
    assert!(
        head.contains("\r\ncontent-type: text/plain; charset=utf-8\r\n"),
        "{head}"
    );
    assert_eq!(body, "not found: the live page is at /\n");
}

#[test]
fn each_answer_says_its_type_and_is_not_cached() {
    let board = new_board();
    let server = LiveServer::start("127.0.0.1:0".parse().unwrap(), board.clone()).unwrap();
    let addr = server.addr();
    for path in ["/", "/index.html", "/?poll=1"] {
        let (code, head, body) = exchange(addr, "GET", path);
        assert_eq!(code, 200, "{path}");
        assert!(
            head.contains("\r\ncontent-type: text/html; charset=utf-8\r\n"),
            "{head}"
        );
        assert!(head.contains("\r\ncache-control: no-store\r\n"), "{head}");
        assert_eq!(body, jdbb::live_web::server::page());
    }
    let (code, head, body) = exchange(addr, "GET", "/state");
    assert_eq!(code, 200);
    assert!(
        head.contains("\r\ncontent-type: application/json\r\n"),
        "{head}"
    );
    assert!(head.contains("\r\ncache-control: no-store\r\n"), "{head}");
    assert_eq!(body, *board.lock().unwrap().json);
    // The stream: the reconnection time first, the board's JSON at once, then, with nothing
    // new, a comment (after a second: not timed here, the order is what is asserted).
    let (head, mut r) = open_stream(addr, "/events");
    assert!(head.starts_with("HTTP/1.1 200"), "{head}");
    let mut lines = vec![];
    while lines.len() < 6 {
        let mut line = String::new();
        assert!(r.read_line(&mut line).unwrap() > 0);
        lines.push(line);
    }
    let json = board.lock().unwrap().json.clone();
    assert_eq!(
        lines,
        [
            "retry: 1000\n".to_string(),
            "\n".into(),
            format!("data: {json}\n"),
            "\n".into(),
            ": idle\n".into(),
            "\n".into()
        ]
    );
}

#[test]
fn at_most_max_streams_pages_stream_at_once() {
    use jdbb::live_web::server::MAX_STREAMS;
    let server = LiveServer::start("127.0.0.1:0".parse().unwrap(), new_board()).unwrap();
    let addr = server.addr();
    let mut open: Vec<_> = (0..MAX_STREAMS)
        .map(|k| {
            let (head, r) = open_stream(addr, "/events");
            assert!(head.starts_with("HTTP/1.1 200"), "stream {k}: {head}");
            r
        })
        .collect();
    let (code, body) = get(addr, "/events");
    assert_eq!(code, 503);
    assert_eq!(body, "too many pages open; close one\n");
    // The page and the state are still served.
    assert_eq!(get(addr, "/state").0, 200);
    // A page closed gives its place back (found at the stream's next write, the comment each
    // second at the latest): refused until then, never anything but 200 or 503. The attempts
    // are counted, not timed (a guard against a hang: at most 100, 0.1 s apart).
    drop(open.pop());
    let mut refused = 0;
    loop {
        let (head, _r) = open_stream(addr, "/events");
        if head.starts_with("HTTP/1.1 200") {
            break;
        }
        assert!(head.starts_with("HTTP/1.1 503"), "{head}");
        refused += 1;
        assert!(refused < 100, "no place after a page closed");
        std::thread::sleep(Duration::from_millis(100));
    }
    println!("a closed page's place was free after {refused} refusals");
}

#[test]
fn dropping_the_server_ends_its_streams_and_its_port() {
    let server = LiveServer::start("127.0.0.1:0".parse().unwrap(), new_board()).unwrap();
    let addr = server.addr();
    let (_, mut r) = open_stream(addr, "/events");
    let mut line = String::new();
    r.read_line(&mut line).unwrap();
    assert_eq!(line, "retry: 1000\n");
    // Dropping it returns (how fast is not a test's business: `cargo bench --bench live`), and
    // then the stream ends: the rest of what was sent, then the end of the body.
    drop(server);
    let mut rest = String::new();
    r.read_to_string(&mut rest).unwrap();
    assert!(
        rest.lines()
            .all(|l| l.is_empty() || l.starts_with("data: ") || l.starts_with(':')),
        "{rest}"
    );
    assert!(TcpStream::connect(addr).is_err(), "still listening");
}

#[test]
fn a_non_local_address_needs_the_token() {
    let server = LiveServer::start("0.0.0.0:0".parse().unwrap(), new_board()).unwrap();
    let token = server.token().unwrap().to_string();
    let addr: SocketAddr = format!("127.0.0.1:{}", server.addr().port())
        .parse()
        .unwrap();
    for path in ["/", "/events", "/state", "/?token=wrong"] {
        let (code, body) = get(addr, path);
        assert_eq!(code, 403, "{path}");
        assert!(body.contains("token"), "{body}");
    }
    assert_eq!(get(addr, &format!("/?token={token}")).0, 200);
    assert_eq!(get(addr, &format!("/state?token={token}")).0, 200);
    let evs = events(
        addr,
        &format!("/events?token={token}"),
        Duration::from_millis(300),
    );
    assert!(!evs.is_empty());
}

/// The server on an ephemeral loopback port with `limits`.
fn limited(board: jdbb::live_web::feed::Board, limits: Limits) -> LiveServer {
    LiveServer::start_with("127.0.0.1:0".parse().unwrap(), board, limits).unwrap()
}

/// Read until the server closes the connection (the end of the stream, or a reset); the bytes
/// read. Panics if one read waits `wait` for nothing: a guard against a hang, much longer than
/// the server's limits under test (no timing is asserted).
fn read_until_closed(s: &mut TcpStream, wait: Duration) -> Vec<u8> {
    use std::io::ErrorKind::{BrokenPipe, ConnectionAborted, ConnectionReset};
    s.set_read_timeout(Some(wait)).unwrap();
    let mut got = vec![];
    let mut buf = vec![0u8; 1 << 16];
    loop {
        match s.read(&mut buf) {
            Ok(0) => return got,
            Ok(n) => got.extend_from_slice(&buf[..n]),
            Err(e) if matches!(e.kind(), ConnectionReset | ConnectionAborted | BrokenPipe) => {
                return got
            }
            Err(e) => panic!(
                "the connection is still open after {wait:?} without data ({e}); {} bytes read",
                got.len()
            ),
        }
    }
}

/// One GET of `path` on the open keep-alive connection `s`: the status code (the body, of its
/// Content-Length, read and dropped).
fn ask(s: &mut TcpStream, addr: SocketAddr, path: &str) -> u16 {
    s.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
    write!(s, "GET {path} HTTP/1.1\r\nHost: {addr}\r\n\r\n").unwrap();
    let mut r = BufReader::new(s.try_clone().unwrap());
    let mut head = String::new();
    loop {
        let mut line = String::new();
        assert!(r.read_line(&mut line).unwrap() > 0, "closed: {head}");
        if line == "\r\n" {
            break;
        }
        head.push_str(&line.to_ascii_lowercase());
    }
    let len: usize = head
        .lines()
        .find_map(|l| l.strip_prefix("content-length: "))
        .unwrap_or_else(|| panic!("no length: {head}"))
        .trim()
        .parse()
        .unwrap();
    let mut body = vec![0; len];
    r.read_exact(&mut body).unwrap();
    head[9..12].parse().unwrap()
}

#[test]
fn connections_beyond_the_cap_are_closed_at_once_and_the_others_keep_working() {
    let limits = Limits {
        max_connections: 4,
        head_timeout: Duration::from_secs(120),
        ..Limits::default()
    };
    let server = limited(new_board(), limits);
    let addr = server.addr();
    // Four connections that send nothing hold the four places.
    let mut held: Vec<TcpStream> = (0..4).map(|_| TcpStream::connect(addr).unwrap()).collect();
    // A fifth is closed without an answer; so is a sixth.
    for _ in 0..2 {
        let mut extra = TcpStream::connect(addr).unwrap();
        let got = read_until_closed(&mut extra, Duration::from_secs(10));
        assert!(got.is_empty(), "{}", String::from_utf8_lossy(&got));
    }
    // The ones held are served, twice each over their keep-alive connections.
    for s in &mut held {
        assert_eq!(ask(s, addr, "/state"), 200);
        assert_eq!(ask(s, addr, "/"), 200);
    }
    // One closed gives its place back (once the server has seen it closed).
    drop(held.pop());
    let mut served = false;
    for _ in 0..100 {
        let mut s = TcpStream::connect(addr).unwrap();
        s.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
        write!(s, "GET /state HTTP/1.1\r\nHost: {addr}\r\n\r\n").unwrap();
        let mut first = [0u8; 12];
        if s.read_exact(&mut first).is_ok() {
            assert_eq!(&first, b"HTTP/1.1 200");
            served = true;
            break;
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    assert!(served, "a closed connection's place never came back");
}

#[test]
fn a_client_that_trickles_its_request_head_is_closed() {
    // Slowloris: a header line every 50 ms, the head never finished.
    let limits = Limits {
        head_timeout: Duration::from_millis(200),
        ..Limits::default()
    };
    let server = limited(new_board(), limits);
    let addr = server.addr();
    let mut s = TcpStream::connect(addr).unwrap();
    write!(s, "GET /state HTTP/1.1\r\nHost: {addr}\r\n").unwrap();
    let mut trickle = s.try_clone().unwrap();
    let dripper = std::thread::spawn(move || {
        // At most 20 s of it; stops when the server has closed.
        for k in 0..400 {
            if write!(trickle, "X-Slow-{k}: 1\r\n").is_err() {
                return true;
            }
            std::thread::sleep(Duration::from_millis(50));
        }
        false
    });
    let got = read_until_closed(&mut s, Duration::from_secs(15));
    let text = String::from_utf8_lossy(&got);
    assert!(!text.contains(" 200 "), "{text}");
    drop(s);
    dripper.join().unwrap();
}

#[test]
fn an_idle_keep_alive_connection_is_closed() {
    let limits = Limits {
        head_timeout: Duration::from_millis(200),
        ..Limits::default()
    };
    let server = limited(new_board(), limits);
    let addr = server.addr();
    let mut s = TcpStream::connect(addr).unwrap();
    // Answered, kept alive (HTTP/1.1), then left idle: closed with nothing more sent.
    assert_eq!(ask(&mut s, addr, "/state"), 200);
    assert_eq!(ask(&mut s, addr, "/state"), 200);
    let got = read_until_closed(&mut s, Duration::from_secs(10));
    assert!(got.is_empty(), "{}", String::from_utf8_lossy(&got));
}

#[test]
fn a_client_that_does_not_read_its_answers_is_closed() {
    // States of 1 MiB, 64 asked for at once, none read: far more than the sockets' buffers.
    let board = new_board();
    {
        let mut b = board.lock().unwrap();
        b.version += 1;
        b.json = Arc::new(format!("{{\"pad\":\"{}\"}}", "x".repeat(1 << 20)));
    }
    let one = board.lock().unwrap().json.len();
    let limits = Limits {
        send_timeout: Duration::from_millis(200),
        ..Limits::default()
    };
    let server = limited(board, limits);
    let addr = server.addr();
    let mut s = TcpStream::connect(addr).unwrap();
    let asked = 64;
    let pipelined = format!("GET /state HTTP/1.1\r\nHost: {addr}\r\n\r\n").repeat(asked);
    s.write_all(pipelined.as_bytes()).unwrap();
    // Read nothing for a while (many times the send timeout): the server gives up on us ...
    std::thread::sleep(Duration::from_secs(3));
    // ... so reading now gets what was in the buffers, then the end: not every answer.
    let got = read_until_closed(&mut s, Duration::from_secs(10));
    println!(
        "{} bytes read of {} asked for before the server closed",
        got.len(),
        asked * one
    );
    assert!(got.len() < asked * one, "{} bytes", got.len());
    // The server still answers others.
    assert_eq!(get(addr, "/state").0, 200);
}

#[test]
fn without_the_token_a_request_is_refused_and_its_connection_closed() {
    let server = LiveServer::start("0.0.0.0:0".parse().unwrap(), new_board()).unwrap();
    let addr: SocketAddr = format!("127.0.0.1:{}", server.addr().port())
        .parse()
        .unwrap();
    let mut s = TcpStream::connect(addr).unwrap();
    // Two requests without the token, kept alive: the first refused, the connection closed
    // before the second is read.
    let two = format!("GET /state HTTP/1.1\r\nHost: {addr}\r\n\r\n").repeat(2);
    s.write_all(two.as_bytes()).unwrap();
    let got = read_until_closed(&mut s, Duration::from_secs(10));
    let text = String::from_utf8_lossy(&got);
    assert!(text.starts_with("HTTP/1.1 403"), "{text}");
    assert_eq!(text.matches("HTTP/1.1 ").count(), 1, "{text}");
    assert!(text.contains("token"), "{text}");
}

#[test]
fn on_loopback_only_requests_naming_this_computer_are_answered() {
    // DNS rebinding: a page of evil.example that renamed itself to 127.0.0.1 sends its own name.
    let server = LiveServer::start("127.0.0.1:0".parse().unwrap(), new_board()).unwrap();
    let addr = server.addr();
    let port = addr.port();
    let send = |head: &str| {
        let mut s = TcpStream::connect(addr).unwrap();
        write!(s, "GET /state {head}\r\n\r\n").unwrap();
        String::from_utf8_lossy(&read_until_closed(&mut s, Duration::from_secs(10))).into_owned()
    };
    for host in [
        format!("evil.example:{port}"),
        "evil.example".into(),
        format!("127.0.0.1.evil.example:{port}"),
        format!("localhost.evil.example:{port}"),
    ] {
        // Kept alive by the client, closed by the server.
        let text = send(&format!("HTTP/1.1\r\nHost: {host}"));
        assert!(text.starts_with("HTTP/1.1 421"), "{host}: {text}");
        assert!(
            text.ends_with(&format!("open http://127.0.0.1:{port}/\n")),
            "{host}: {text}"
        );
    }
    // No Host at all (HTTP/1.0 allows it).
    let text = send("HTTP/1.0");
    assert_eq!(text.get(9..12), Some("421"), "{text}");
    // This computer's names; any port (a port forwarded to this one, as by an SSH tunnel).
    for host in [
        format!("127.0.0.1:{port}"),
        format!("localhost:{port}"),
        format!("[::1]:{port}"),
        "localhost:9000".into(),
    ] {
        let text = send(&format!("HTTP/1.1\r\nHost: {host}\r\nConnection: close"));
        assert!(text.starts_with("HTTP/1.1 200"), "{host}: {text}");
    }
}

#[test]
fn a_stalled_page_costs_the_feed_nothing() {
    // A client that opens the stream and never reads: the feed publishes as fast as ever.
    let board = new_board();
    let server = LiveServer::start("127.0.0.1:0".parse().unwrap(), board.clone()).unwrap();
    let addr = server.addr();
    let mut stalled = vec![];
    for _ in 0..4 {
        let mut s = TcpStream::connect(addr).unwrap();
        write!(s, "GET /events HTTP/1.1\r\nHost: {addr}\r\n\r\n").unwrap();
        stalled.push(s);
    }
    let plan = test_plan();
    let d = synthetic_d(&plan);
    let mut feed = LiveFeed::new(board.clone(), Some(&plan), None);
    let mut stats = Stats::default();
    let mut publications = 0u32;
    let mut pauses = 0u32;
    for (b, chunk) in d.chunks(100).enumerate() {
        let batch: Vec<SeqSample> = chunk
            .iter()
            .enumerate()
            .map(|(i, &d_mm)| SeqSample {
                seq: (b * 100 + i) as u64,
                sample: Sample {
                    t_us: 1000 * (b * 100 + i) as u64,
                    enc1: 0,
                    enc2: 0,
                    d_mm,
                    status: Status(0),
                },
            })
            .collect();
        stats.samples += 100;
        feed.samples(&batch);
        let before = board.lock().unwrap().version;
        feed.publish_if_due(&stats, Instant::now());
        publications += u32::from(board.lock().unwrap().version != before);
        if b % 50 == 0 {
            // Let publications fall due (40 ms) now and then.
            std::thread::sleep(Duration::from_millis(50));
            pauses += 1;
        }
    }
    // Every sample was taken and a publication fell due at each pause at least: the stalled
    // pages held nothing up (a blocked feed would hang here). What the feed costs the recorder
    // is measured, not bounded here: `cargo bench -p jdbb --bench live` (1).
    println!(
        "{} samples fed; {publications} publications over {pauses} pauses",
        d.len()
    );
    assert_eq!(stats.samples, d.len().div_ceil(100) as u64 * 100);
    assert!(publications >= pauses, "{publications} publications");
    // Now stall them for good: 40 states of 1 MB each, more than the sockets' buffers hold. The
    // server still answers others (a stalled page holds no thread), and stopping it ends the
    // stalled pages' connections (after its limit: the bench times it) and its port.
    let big = Arc::new(format!("{{\"pad\":\"{}\"}}", "x".repeat(1 << 20)));
    for _ in 0..40 {
        {
            let mut b = board.lock().unwrap();
            b.version += 1;
            b.json = big.clone();
        }
        std::thread::sleep(Duration::from_millis(25));
    }
    let (code, body) = get(addr, "/state");
    assert_eq!((code, body.len()), (200, big.len()));
    drop(server);
    assert!(TcpStream::connect(addr).is_err(), "still listening");
    // Each stalled page, read now, gets what its buffers held and then the end (a guard of 10 s
    // per read against a hang, no timing asserted).
    for mut s in stalled {
        read_until_closed(&mut s, Duration::from_secs(10));
    }
}

fn jdbb(args: &[&str]) -> std::process::Output {
    std::process::Command::new(env!("CARGO_BIN_EXE_jdbb"))
        .args(args)
        .output()
        .unwrap()
}

#[test]
fn bad_web_options_fail_clearly_and_leave_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("rec.csv");
    let out_s = out.to_str().unwrap();
    // An address in use: said before any port or file is touched.
    let busy = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = busy.local_addr().unwrap().to_string();
    let o = jdbb(&[
        "record",
        "--port",
        "/dev/nonexistent-jdbb",
        "--out",
        out_s,
        "--web",
        &addr,
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(
        err.contains(&format!("cannot serve the live page on {addr}")),
        "{err}"
    );
    assert!(err.contains("Give another --web ADDR"), "{err}");
    assert!(!out.exists() && !dir.path().join("rec.csv.partial").exists());
    // A plan that is not there: bad input (2), nothing created.
    let o = jdbb(&[
        "record",
        "--port",
        "/dev/nonexistent-jdbb",
        "--out",
        out_s,
        "--web",
        "127.0.0.1:0",
        "--plan",
        "no-such-plan.json",
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(err.contains("no-such-plan.json"), "{err}");
    assert!(!out.exists() && !dir.path().join("rec.csv.partial").exists());
    // The end-of-test verdict needs the plan: --tolerance-um without --plan is refused.
    let o = jdbb(&[
        "record",
        "--port",
        "x",
        "--out",
        out_s,
        "--tolerance-um",
        "10",
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(err.contains("--plan"), "{err}");
    // Not an address.
    let o = jdbb(&["live", "--port", "x", "--web", "localhost-ish"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("--web"));
}

/// The diagnosis while recording on a machine that runs at 103 % override, accelerates at
/// 600 mm/s² and has 8 µm of play on X and 30 µm/m out of square in XY, sampled at 1 kHz with
/// 0.2 µm noise and a +40 ppm clock. The record comes from `jdbb simulate --plan`'s machine (the
/// host's own model: a round trip — what this checks is the preview's timing, not the models).
/// Circle 2 is diagnosed before its feed-out, timed at circle 1's feed; both circles name the
/// play and the squareness within 5 % and nothing else.
#[test]
fn each_circle_names_the_hidden_effects_and_circle_2_before_its_feed_out() {
    let plan = test_plan();
    let machine = jdbb::simulate::machine::Machine::parse(
        std::path::Path::new("m.toml"),
        "feed_override_pct = 103\naccel_mm_s2 = 600\n\
         [instrument]\nsample_rate_hz = 1000\nnoise_um = 0.2\nclock_ppm = 40\n\
         [effects]\nbacklash_x = 8.0\nsquareness_xy = 30.0\n",
    )
    .unwrap();
    let (samples, _) = jdbb::simulate::record_sim::record(&plan, &machine).unwrap();
    let mut feed = LiveFeed::new(new_board(), Some(&plan), Some(20.0));
    let mut stats = Stats::default();
    // Fed 100 samples at a time with a pause while the worker runs.
    for (b, chunk) in samples.chunks(100).enumerate() {
        let batch: Vec<SeqSample> = chunk
            .iter()
            .enumerate()
            .map(|(i, s)| SeqSample {
                seq: (b * 100 + i) as u64,
                sample: *s,
            })
            .collect();
        stats.samples += batch.len() as u64;
        feed.samples(&batch);
        // Give the worker time for what it has (it reads the samples in order, so a slow build
        // only delays the answer, never changes it).
        std::thread::sleep(Duration::from_millis(2));
        feed.publish_if_due(&stats, Instant::now() + Duration::from_secs(b as u64));
    }
    let t0 = Instant::now();
    while feed.circle_diagnoses().len() < 2 && t0.elapsed() < Duration::from_secs(300) {
        std::thread::sleep(Duration::from_millis(50));
        feed.publish_if_due(&stats, Instant::now() + Duration::from_secs(1_000_000));
    }
    let list = feed.circle_diagnoses();
    assert_eq!(list.len(), 2);
    for c in list {
        println!("circle {} ({} ms):\n{}", c.circle, c.took_ms, c.text);
        let named: Vec<(&str, f64)> = c
            .effects
            .iter()
            .skip(2)
            .map(|e| {
                let v: f64 = e.value.split(' ').next().unwrap().parse().unwrap();
                (e.name.as_str(), v)
            })
            .collect();
        assert_eq!(named.len(), 2, "{}", c.text);
        for (name, truth) in [("backlash_x", 8.0), ("squareness_xy", 30.0)] {
            let v = named
                .iter()
                .find(|n| n.0 == name)
                .unwrap_or_else(|| panic!("{name} not named:\n{}", c.text))
                .1;
            assert!((v / truth - 1.0).abs() < 0.05, "{name} {v}:\n{}", c.text);
        }
    }
    assert!(
        list[1]
            .text
            .contains("circle 2 timed from its feed-in at the feed of the circle before it"),
        "{}",
        list[1].text
    );
}

#[test]
fn the_page_shows_every_warning_as_it_comes_and_the_verdict() {
    use jdbb::live_web::state::Verdict;
    let board = new_board();
    let server = LiveServer::start("127.0.0.1:0".parse().unwrap(), board.clone()).unwrap();
    let addr = server.addr();
    let plan = test_plan();
    let mut feed = LiveFeed::new(board, Some(&plan), None);
    let stats = Stats::default();
    let state = || -> serde_json::Value { serde_json::from_str(&get(addr, "/state").1).unwrap() };
    feed.publish_if_due(&stats, Instant::now());
    assert_eq!(state()["warnings"], serde_json::json!([]));
    // A warning said on the terminal (here the missed cycle start's) is on the next publication,
    // which is due at once, not after the publication interval.
    let missed = "warning: D was already moving when the record started (cycle start missed?)";
    feed.warn(missed);
    feed.warn(missed);
    feed.publish_if_due(&stats, Instant::now());
    let st = state();
    assert_eq!(st["warnings"], serde_json::json!([missed]), "{st}");
    // The verdict, as its own field the page shows large.
    feed.diagnosis(
        &stats,
        "…\nFAIL: largest circular deviation G 12 µm\n",
        Some(Verdict {
            pass: false,
            text: "FAIL: largest circular deviation G 12 µm".into(),
        }),
    );
    let st = state();
    assert_eq!(st["verdict"]["pass"], false, "{st}");
    assert_eq!(st["warnings"][0], missed);
    // The page has the places for them at its top, before the figures.
    let page = get(addr, "/").1;
    let (v, w, fig) = (
        page.find("id=\"verdict\"").unwrap(),
        page.find("id=\"warnings\"").unwrap(),
        page.find("class=\"figures\"").unwrap(),
    );
    assert!(v < fig && w < fig);
    assert!(page.contains("st.warnings") && page.contains("st.verdict"));
}

#[test]
fn a_page_on_every_address_gets_a_url_a_person_can_open() {
    let server = LiveServer::start("0.0.0.0:0".parse().unwrap(), new_board()).unwrap();
    let url = server.url();
    let note = server.url_note().expect("a note on 0.0.0.0");
    // Either the URL names this computer's address, or the note says what to put for 0.0.0.0.
    assert!(
        !url.contains("//0.0.0.0:") || note.contains("in place of 0.0.0.0"),
        "{url}; {note}"
    );
    assert!(
        url.contains(&format!(":{}/?token=", server.addr().port())),
        "{url}"
    );
    let local = LiveServer::start("127.0.0.1:0".parse().unwrap(), new_board()).unwrap();
    assert!(local.url_note().is_none());
    assert!(local.url().starts_with("http://127.0.0.1:"));
}
