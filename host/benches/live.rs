//! The live page's cost (issue 18 §5): (1) what the feed costs the recorder — following the plan
//! and publishing the state with its trace 25 times a second — for a 5 kHz test, as a share of one
//! core; (2) how long after a circle's last data sample its diagnosis is on the board, for the
//! second circle of a test at 5 kHz streamed in real time (the worker's synchronisation of the
//! running circle and its diagnosis, and the next publication); (3) what the server's thread
//! costs while two pages stream 100 kB states 25 times a second and a third polls `/state` ten
//! times a second (its own CPU time, from /proc); (4) how long stopping the server takes with
//! pages that stopped reading (its limit, `SHUTDOWN_LIMIT`, and no longer). The tests assert
//! order, counts and state only (docs/tests.md); these are the times.
//!
//! Run: `cargo bench -p jdbb --bench live` (release profile). Goals: (1) < 5 % of a core,
//! (2) ≤ 200 ms, (3) < 5 % of a core (the recorder's allowance, issue 18), (4) the limit.
use std::io::{Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use jdbb::link::stream::{SeqSample, Stats};
use jdbb::live_web::feed::{new_board, LiveFeed};
use jdbb::live_web::server::{LiveServer, SHUTDOWN_LIMIT};
use jdbb::plan::build::{plan, PlanSpec};
use jdbb::plan::{Dialect, Plan, Plane, Segment};
use jdbb_core::protocol::{Sample, Status};

const RATE_HZ: f64 = 5000.0;

/// D along `plan` at its programmed feed sampled at [`RATE_HZ`], from its first motion after the
/// operator's stop, with a 2 µm once-per-revolution wobble (a centring error) and 0.2 µm of
/// deterministic ripple.
fn synthetic(plan: &Plan) -> Vec<f64> {
    let c = plan.centre_mm;
    let dist = |p: [f64; 3]| {
        ((p[0] - c[0]).powi(2) + (p[1] - c[1]).powi(2) + (p[2] - c[2]).powi(2)).sqrt()
    };
    let first = plan
        .segments
        .iter()
        .position(|s| matches!(s, Segment::Stop))
        .expect("a plan has the operator's stop")
        + 1;
    let dt = 1.0 / RATE_HZ;
    let mut here = plan.start_mm;
    let mut d: Vec<f64> = std::iter::repeat_n(dist(here), RATE_HZ as usize).collect();
    for (i, s) in plan.segments.iter().enumerate().skip(first) {
        let Some(dur) = s.nominal_duration_s() else {
            continue;
        };
        let n = (dur / dt).round() as usize;
        for k in 0..n {
            let p = match s {
                Segment::Dwell { .. } => here,
                _ => plan.position_at(i, s.length_mm() * (k as f64 + 0.5) / n as f64),
            };
            let a = (p[1] - c[1]).atan2(p[0] - c[0]);
            d.push(dist(p) + 2e-3 * a.cos() + 2e-4 * (d.len() as f64 * 0.37).sin());
        }
        if let Some(to) = s.to_mm() {
            here = to;
        }
    }
    d.extend(std::iter::repeat_n(dist(here), RATE_HZ as usize));
    d
}

/// The recorder's batch of samples `d_mm` from sample `first` on, at 5 kHz.
fn batch(d_mm: &[f64], first: usize) -> Vec<SeqSample> {
    d_mm.iter()
        .enumerate()
        .map(|(i, &d_mm)| {
            let seq = (first + i) as u64;
            SeqSample {
                seq,
                sample: Sample {
                    t_us: 200 * seq,
                    enc1: 0,
                    enc2: 0,
                    d_mm,
                    status: Status(0),
                },
            }
        })
        .collect()
}

fn main() {
    let spec = PlanSpec::machine_test(
        &[90.0],
        &[0.0],
        Plane::Xy,
        4000.0,
        [0.0, 0.0, 0.0],
        Dialect::Linuxcnc,
    );
    let plan1 = plan(&spec, &jdbb_core::calib::Calibration::DEFAULT).expect("the plan");
    let d = synthetic(&plan1);
    let device_s = d.len() as f64 / RATE_HZ;

    // (1) The feed, batches of 50 samples (10 ms at 5 kHz, a read of the recorder), the clock
    // the feed sees advancing with the device's time so that it publishes every 40 ms.
    let board = new_board();
    let mut feed = LiveFeed::new(board.clone(), Some(&plan1), None);
    let mut stats = Stats::default();
    let base = Instant::now();
    let t0 = Instant::now();
    for (b, chunk) in d.chunks(50).enumerate() {
        let batch = batch(chunk, b * 50);
        stats.samples += batch.len() as u64;
        feed.samples(&batch);
        let now = base + Duration::from_micros(200 * stats.samples);
        feed.publish_if_due(&stats, now);
    }
    let wall = t0.elapsed().as_secs_f64();
    let version = board.lock().map(|b| b.version).unwrap_or(0);
    println!(
        "feed: {} samples ({device_s:.1} s at 5 kHz), {version} publications, in {:.3} s: {:.2} % of a core (goal < 5 %)",
        d.len(),
        wall,
        100.0 * wall / device_s
    );
    drop(feed);

    // (2) The diagnosis while recording of circle 2 of a two-circle test, from its last data
    // sample (where the finished record's synchronisation puts the end of its last data arc) to
    // the publication that carries it. The samples go to the feed as the recorder gives them:
    // as fast as it takes them up to a second before that sample (then a pause, so the worker
    // has caught up), then in real time, 50 samples every 10 ms.
    let spec = PlanSpec::machine_test(
        &[85.0, 95.0],
        &[0.0],
        Plane::Xy,
        4000.0,
        [0.0, 0.0, 0.0],
        Dialect::Linuxcnc,
    );
    let plan2 = plan(&spec, &jdbb_core::calib::Calibration::DEFAULT).expect("the plan");
    let d2 = synthetic(&plan2);
    let t_s: Vec<f64> = (0..d2.len()).map(|i| i as f64 / RATE_HZ).collect();
    let rec =
        jdbb::sync::Record::from_samples(std::path::Path::new("bench"), t_s.clone(), d2.clone());
    let t = Instant::now();
    let full = jdbb::sync::synchronise(&plan2, &rec).expect("synchronised");
    let t_sync = t.elapsed();
    let last_data_s = full.circles[1]
        .data
        .iter()
        .map(|a| a.t_end_s)
        .fold(f64::NEG_INFINITY, f64::max);
    let board = new_board();
    let mut feed = LiveFeed::new(board.clone(), Some(&plan2), Some(20.0));
    let mut stats = Stats::default();
    let shown = |board: &jdbb::live_web::feed::Board| -> usize {
        let b = board.lock().expect("the board");
        let v: serde_json::Value = serde_json::from_str(&b.json).expect("the state's JSON");
        v["circle_diagnoses"].as_array().map_or(0, Vec::len)
    };
    let mut sent_last_data: Option<Instant> = None;
    let mut paced: Option<Instant> = None;
    let mut latency_ms = f64::NAN;
    let mut took_ms = f64::NAN;
    for (b, chunk) in d2.chunks(50).enumerate() {
        let t_first = t_s[b * 50];
        if t_first >= last_data_s - 1.0 && paced.is_none() {
            // Let the worker catch up (circle 1's diagnosis is on the board), then real time.
            let wait = Instant::now();
            while shown(&board) < 1 && wait.elapsed() < Duration::from_secs(30) {
                feed.publish_if_due(&stats, Instant::now());
                std::thread::sleep(Duration::from_millis(5));
            }
            std::thread::sleep(Duration::from_millis(500));
            paced = Some(Instant::now());
        }
        if let Some(p0) = paced {
            let due = p0 + Duration::from_secs_f64(t_first - (last_data_s - 1.0));
            if let Some(w) = due.checked_duration_since(Instant::now()) {
                std::thread::sleep(w);
            }
        }
        let batch = batch(chunk, b * 50);
        stats.samples += batch.len() as u64;
        feed.samples(&batch);
        if sent_last_data.is_none() && t_s[b * 50 + chunk.len() - 1] >= last_data_s {
            sent_last_data = Some(Instant::now());
        }
        feed.publish_if_due(&stats, Instant::now());
        if let Some(t0) = sent_last_data {
            if shown(&board) >= 2 {
                latency_ms = t0.elapsed().as_secs_f64() * 1e3;
                took_ms = feed.circle_diagnoses()[1].took_ms;
                break;
            }
        }
    }
    let c2 = &feed.circle_diagnoses()[1];
    println!(
        "diagnosis of circle 2 ({} samples at 5 kHz, R 95 mm at 4000 mm/min): on the board {latency_ms:.0} ms after its last data sample ({took_ms:.0} ms of work; goal ≤ 200 ms); {}",
        d2.len(),
        c2.text
            .lines()
            .find(|l| l.starts_with("timing:"))
            .unwrap_or("")
    );
    let end_of_circle_2 = full.circles[1].feed_out.profile.t0_s;
    println!(
        "  its feed-out starts {:.2} s after that sample; synchronising the whole finished record takes {:.0} ms",
        end_of_circle_2 - last_data_s,
        t_sync.as_secs_f64() * 1e3
    );

    server_cpu();
    stalled_stop();
}

/// CPU time (user + system) of this process's thread named `name`, from /proc.
fn named_thread_cpu(name: &str) -> Option<Duration> {
    // SAFETY: sysconf only reads a setting.
    let tick = 1.0 / unsafe { libc::sysconf(libc::_SC_CLK_TCK) } as f64;
    for task in std::fs::read_dir("/proc/self/task").ok()? {
        let dir = task.ok()?.path();
        let comm = std::fs::read_to_string(dir.join("comm")).ok()?;
        if comm.trim_end() == name {
            let stat = std::fs::read_to_string(dir.join("stat")).ok()?;
            let after = &stat[stat.rfind(')')? + 2..];
            let f: Vec<&str> = after.split(' ').collect();
            let (u, s): (f64, f64) = (f[11].parse().ok()?, f[12].parse().ok()?);
            return Some(Duration::from_secs_f64((u + s) * tick));
        }
    }
    None
}

/// A page's connection to `/events`, its request sent.
fn page(addr: SocketAddr) -> TcpStream {
    let mut s = TcpStream::connect(addr).expect("connect");
    write!(s, "GET /events HTTP/1.1\r\nHost: {addr}\r\n\r\n").expect("send");
    s
}

/// (3) The server's thread while two pages read the stream and a third polls.
fn server_cpu() {
    let board = new_board();
    let server = LiveServer::start("127.0.0.1:0".parse().expect("address"), board.clone())
        .expect("the server");
    let addr = server.addr();
    let stop = Arc::new(AtomicBool::new(false));
    let readers: Vec<_> = (0..2)
        .map(|_| {
            let stop = stop.clone();
            std::thread::spawn(move || {
                let mut s = page(addr);
                s.set_read_timeout(Some(Duration::from_secs(2)))
                    .expect("timeout");
                let (mut n, mut buf) = (0usize, vec![0u8; 1 << 16]);
                while !stop.load(Ordering::SeqCst) {
                    match s.read(&mut buf) {
                        Ok(0) | Err(_) => break,
                        Ok(k) => n += k,
                    }
                }
                n
            })
        })
        .collect();
    let json = Arc::new(format!("{{\"pad\":\"{}\"}}", "x".repeat(100_000)));
    // (The thread names itself once it runs.)
    let cpu0 = loop {
        if let Some(c) = named_thread_cpu("jdbb-web") {
            break c;
        }
        std::thread::sleep(Duration::from_millis(10));
    };
    let t0 = Instant::now();
    let mut polls = 0u128;
    while t0.elapsed() < Duration::from_secs(5) {
        if let Ok(mut b) = board.lock() {
            b.version += 1;
            b.json = json.clone();
        }
        std::thread::sleep(Duration::from_millis(40));
        if polls * 100 < t0.elapsed().as_millis() {
            let mut s = TcpStream::connect(addr).expect("connect");
            write!(s, "GET /state HTTP/1.0\r\nHost: {addr}\r\n\r\n").expect("send");
            let mut text = String::new();
            s.read_to_string(&mut text).expect("the state");
            polls += 1;
        }
    }
    let cpu = named_thread_cpu("jdbb-web").unwrap_or_default() - cpu0;
    let wall = t0.elapsed();
    stop.store(true, Ordering::SeqCst);
    let bytes: Vec<usize> = readers.into_iter().map(|r| r.join().unwrap_or(0)).collect();
    println!(
        "server thread: {cpu:?} CPU over {wall:?}: {:.2} % of a core (goal < 5 %); pages read {bytes:?} bytes, {polls} polls",
        100.0 * cpu.as_secs_f64() / wall.as_secs_f64()
    );
    drop(server);
}

/// (4) Stopping the server with four pages that never read, 40 states of 1 MB published to them.
fn stalled_stop() {
    let board = new_board();
    let server = LiveServer::start("127.0.0.1:0".parse().expect("address"), board.clone())
        .expect("the server");
    let addr = server.addr();
    let stalled: Vec<TcpStream> = (0..4).map(|_| page(addr)).collect();
    let big = Arc::new(format!("{{\"pad\":\"{}\"}}", "x".repeat(1 << 20)));
    for _ in 0..40 {
        if let Ok(mut b) = board.lock() {
            b.version += 1;
            b.json = big.clone();
        }
        std::thread::sleep(Duration::from_millis(25));
    }
    let t = Instant::now();
    let mut s = TcpStream::connect(addr).expect("connect");
    write!(s, "GET /state HTTP/1.0\r\nHost: {addr}\r\n\r\n").expect("send");
    let mut text = String::new();
    s.read_to_string(&mut text).expect("the state");
    let state_took = t.elapsed();
    let t = Instant::now();
    drop(server);
    println!(
        "with 4 stalled pages: /state answered in {state_took:?}; the server stopped in {:?} (limit {SHUTDOWN_LIMIT:?})",
        t.elapsed()
    );
    drop(stalled);
}
