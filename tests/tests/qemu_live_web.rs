//! The live page on a real planned test (issue 18): the QEMU scenario of `qemu_scenario.rs` (a
//! LinuxCNC program from `jdbb plan` run by the G-code machine simulator with a hidden 6 µm X
//! backlash and a 20 µm/m XY squareness error, played by the firmware in QEMU at 5 kHz) recorded
//! with `jdbb record --web 127.0.0.1:0 --plan plan.json --tolerance-um 20`:
//!
//! - a plain TCP client reads the event stream during the whole run: at least 10 events a second,
//!   the phases in the plan's order (feed-in, circle ccw, circle cw, done), a trace of
//!   hundreds of points on the circle, the samples counted as the record holds them;
//! - headless Chromium loads the page (`?poll=1`: it reads `/state` ten times a second, since an
//!   open event stream keeps headless Chromium's virtual time from running out) while the circle runs: the DOM shows the progress and a
//!   trace with points; a screenshot is kept (`$CARGO_TARGET_TMPDIR/live_page.png`, and
//!   `live_page_diagnosis.png` once the circle's diagnosis is on the page). Without
//!   Chromium that part says it is skipped and why (fails with `JDBB_REQUIRE_CHROMIUM=1`);
//! - after the circle the diagnosis of the circle comes on the event stream and in Chromium's
//!   DOM, PASS, naming the hidden effects (`record --plan` stops by itself 3 s after the
//!   program; the page stays up with its final state until the operator's Ctrl-C);
//! - the record is whole (seq from 0 without a gap, 200 µs apart), and the end-of-test
//!   diagnosis `record` prints is exactly what `jdbb diagnose --record --plan --tolerance-um`
//!   prints for the finished file, naming the hidden effects.
use std::io::{BufRead, BufReader, Write};
use std::net::{SocketAddr, TcpStream};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use jdbb_tests::gmachine::{Axis, Dialect, MachineErrors, SimConfig, Simulation, Squareness};
use jdbb_tests::{jdbb_bin, qemu_available, qemu_elf, Qemu};

const RATE_HZ: u32 = 5_000;

fn find_chromium() -> Option<PathBuf> {
    if let Ok(p) = std::env::var("JDBB_CHROMIUM") {
        return Some(PathBuf::from(p));
    }
    let path = std::env::var_os("PATH")?;
    for name in [
        "chromium",
        "chromium-browser",
        "chromium-headless-shell",
        "google-chrome",
    ] {
        for dir in std::env::split_paths(&path) {
            let p = dir.join(name);
            if p.is_file() {
                return Some(p);
            }
        }
    }
    None
}

/// Run headless Chromium on `url` with `args` (after the common ones); its stdout.
fn chromium(bin: &Path, profile: &Path, args: &[String], url: &str) -> String {
    let mut child = Command::new(bin)
        .args([
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--disable-quic",
            "--no-first-run",
            "--disable-background-networking",
            "--disable-component-update",
            "--disable-sync",
            "--hide-scrollbars",
            &format!("--user-data-dir={}", profile.display()),
            "--window-size=1000,1200",
        ])
        .args(args)
        .arg(url)
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let mut out = String::new();
    let mut stdout = child.stdout.take().unwrap();
    let reader = std::thread::spawn(move || {
        let mut s = String::new();
        let _ = std::io::Read::read_to_string(&mut stdout, &mut s);
        s
    });
    let t0 = Instant::now();
    loop {
        if child.try_wait().unwrap().is_some() {
            break;
        }
        if t0.elapsed() > Duration::from_secs(60) {
            let _ = child.kill();
            panic!("chromium did not finish in 60 s");
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    out.push_str(&reader.join().unwrap());
    out
}

/// Read the event stream until the server closes it; each event's JSON to `tx`.
fn read_events(addr: SocketAddr, tx: mpsc::Sender<(Instant, serde_json::Value)>) {
    let mut s = TcpStream::connect(addr).unwrap();
    // HTTP/1.0: the body as it is, ended by the close (over HTTP/1.1 it would come chunked;
    // host/tests/live_web.rs reads it so).
    write!(s, "GET /events HTTP/1.0\r\nHost: {addr}\r\n\r\n").unwrap();
    let r = BufReader::new(s);
    for line in r.lines() {
        let Ok(line) = line else { break };
        if let Some(json) = line.strip_prefix("data: ") {
            if tx
                .send((Instant::now(), serde_json::from_str(json).unwrap()))
                .is_err()
            {
                break;
            }
        }
    }
}

#[test]
fn the_live_page_follows_a_qemu_test_and_diagnoses_it_at_the_end() {
    let elf = qemu_elf("jdbb-firmware");
    if !qemu_available(&elf) {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let plan_dir = dir.path().join("plan");
    let out = Command::new(jdbb_bin())
        .args([
            "plan",
            "--radius",
            "90",
            "--feed",
            "4000",
            "--centre",
            "100,50,-20",
            "--out",
        ])
        .arg(&plan_dir)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let program = std::fs::read_to_string(plan_dir.join("ballbar.ngc")).unwrap();
    let mut cfg = SimConfig::new(Dialect::LinuxCnc, [100.0, 50.0, -20.0]);
    cfg.errors = MachineErrors {
        backlash_um: [6.0, 0.0, 0.0],
        squareness: vec![Squareness {
            axis: Axis::X,
            by: Axis::Y,
            um_per_m: 20.0,
        }],
        setup_offset_um: [25.0, -15.0, 0.0],
        ..MachineErrors::default()
    };
    cfg.machine.feed_override_pct = 97.0;
    cfg.instrument.sample_rate_hz = f64::from(RATE_HZ);
    cfg.instrument.clock_ppm = 37.0;
    cfg.instrument.noise_um = 0.2;
    cfg.instrument.start_delay_s = 2.5;
    // A long tail after the program: the diagnosis of the circle (seconds of work in a debug
    // build) comes while the recorder still runs, and Chromium loads the page again to see it.
    cfg.instrument.tail_s = 45.0;
    cfg.instrument.seed = 11;
    let sim = Simulation::new(&program, cfg).unwrap();
    let scenario = dir.path().join("scenario.bin");
    let mut f = std::io::BufWriter::new(std::fs::File::create(&scenario).unwrap());
    let n = sim.write_scenario(&mut f).unwrap().n_samples as u64;
    drop(f);
    let (_qemu, pty) = Qemu::start_with_scenario(&elf, &scenario);

    let rec = dir.path().join("rec.csv");
    let plan_json = plan_dir.join("plan.json");
    let mut recorder = Command::new(jdbb_bin())
        .args([
            "record",
            "--rate",
            &RATE_HZ.to_string(),
            "--web",
            "127.0.0.1:0",
        ])
        .arg("--plan")
        .arg(&plan_json)
        .args(["--tolerance-um", "20", "--port"])
        .arg(&pty)
        .arg("--out")
        .arg(&rec)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // The URL, from stderr; the rest of stderr kept for the end.
    let (line_tx, line_rx) = mpsc::channel::<String>();
    let stderr = recorder.stderr.take().unwrap();
    let err_thread = std::thread::spawn(move || {
        let mut all = String::new();
        for line in BufReader::new(stderr).lines().map_while(Result::ok) {
            let _ = line_tx.send(line.clone());
            all.push_str(&line);
            all.push('\n');
        }
        all
    });
    let url = loop {
        let line = line_rx
            .recv_timeout(Duration::from_secs(30))
            .expect("jdbb record printed no live page URL");
        if let Some(u) = line.strip_prefix("live page: ") {
            break u.to_string();
        }
    };
    println!("live page: {url}");
    let addr: SocketAddr = url
        .trim_start_matches("http://")
        .trim_end_matches('/')
        .parse()
        .unwrap();
    assert_ne!(addr.port(), 0, "the bound port is printed");
    let (ev_tx, ev_rx) = mpsc::channel();
    let ev_thread = std::thread::spawn(move || read_events(addr, ev_tx));

    // Follow the events; on the circle's cw data arc, load the page in Chromium.
    let chromium_bin = find_chromium();
    if chromium_bin.is_none() {
        assert!(
            std::env::var("JDBB_REQUIRE_CHROMIUM").as_deref() != Ok("1"),
            "JDBB_REQUIRE_CHROMIUM=1 but no chromium found (PATH, JDBB_CHROMIUM)"
        );
        println!("skipped the browser part: no chromium (or chromium-browser, google-chrome) on PATH and no JDBB_CHROMIUM");
    }
    let mut browser_done = chromium_bin.is_none();
    let mut browser_diagnosis_done = chromium_bin.is_none();
    let mut events = vec![];
    let t0 = Instant::now();
    let partial = dir.path().join("rec.csv.partial");
    let mut interrupted = false;
    loop {
        match ev_rx.recv_timeout(Duration::from_millis(200)) {
            Ok(ev) => {
                let v = &ev.1;
                let on_cw = v["progress"]["phase"] == "circle"
                    && v["progress"]["sense"] == "cw"
                    && v["progress"]["on_data_arc"] == true;
                let has_diagnosis = v["circle_diagnoses"]
                    .as_array()
                    .is_some_and(|l| !l.is_empty());
                events.push(ev);
                if has_diagnosis && !browser_diagnosis_done {
                    browser_diagnosis_done = true;
                    let bin = chromium_bin.as_ref().unwrap();
                    let dom = chromium(
                        bin,
                        &dir.path().join("profile"),
                        &["--virtual-time-budget=2000".into(), "--dump-dom".into()],
                        &format!("{url}?poll=1"),
                    );
                    assert!(dom.contains("Diagnosis of circle 1: PASS"), "{dom}");
                    // The ranked effects as a table, one row per effect.
                    assert!(
                        dom.contains("data-effect=\"backlash_x\"")
                            && dom.contains("data-effect=\"squareness_xy\""),
                        "{dom}"
                    );
                    println!("Chromium's DOM: the circle's diagnosis, a table naming backlash_x and squareness_xy");
                    let png =
                        PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("live_page_diagnosis.png");
                    chromium(
                        bin,
                        &dir.path().join("profile"),
                        &[
                            "--virtual-time-budget=2000".into(),
                            "--window-size=1000,2400".into(),
                            format!("--screenshot={}", png.display()),
                        ],
                        &format!("{url}?poll=1"),
                    );
                    let size = std::fs::metadata(&png).map(|m| m.len()).unwrap_or(0);
                    assert!(size > 10_000, "screenshot of {size} bytes");
                    println!("screenshot: {} ({size} bytes)", png.display());
                }
                if on_cw && !browser_done {
                    browser_done = true;
                    let bin = chromium_bin.as_ref().unwrap();
                    let profile = dir.path().join("profile");
                    // ?poll=1: the page reads /state; an open event stream would keep Chromium's
                    // virtual time from ever running out (it waits for an idle network).
                    let page = format!("{url}?poll=1");
                    let dom = chromium(
                        bin,
                        &profile,
                        &["--virtual-time-budget=2000".into(), "--dump-dom".into()],
                        &page,
                    );
                    assert!(dom.contains("circle 1 of 1"), "{dom}");
                    let pts: usize = dom
                        .split("id=\"polar\"")
                        .nth(1)
                        .and_then(|s| s.split("data-points=\"").nth(1))
                        .and_then(|s| s.split('"').next())
                        .and_then(|s| s.parse().ok())
                        .unwrap_or(0);
                    println!("Chromium's DOM: progress shown, the trace has {pts} points");
                    assert!(pts > 200, "trace points in the DOM: {pts}");
                    let png = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("live_page.png");
                    chromium(
                        bin,
                        &profile,
                        &[
                            "--virtual-time-budget=2000".into(),
                            format!("--screenshot={}", png.display()),
                        ],
                        &page,
                    );
                    let size = std::fs::metadata(&png).map(|m| m.len()).unwrap_or(0);
                    assert!(size > 10_000, "screenshot of {size} bytes");
                    println!("screenshot: {} ({size} bytes)", png.display());
                }
            }
            Err(mpsc::RecvTimeoutError::Timeout) => {}
            Err(mpsc::RecvTimeoutError::Disconnected) => break,
        }
        // The scenario played out: the operator's Ctrl-C — while recording, or once the record
        // has stopped by itself after the plan's program (the page then stays up with its
        // final state until Ctrl-C) and the page's diagnosis has been read.
        let stopped_by_itself = dir.path().join("rec.csv").exists() && browser_diagnosis_done;
        if !interrupted
            && (stopped_by_itself
                || std::fs::read_to_string(&partial)
                    .map(|t| t.lines().count() as u64 > n + 1_000)
                    .unwrap_or(false))
        {
            interrupted = true;
            let kill = Command::new("kill")
                .args(["-INT", &recorder.id().to_string()])
                .status()
                .unwrap();
            assert!(kill.success());
        }
        assert!(
            t0.elapsed() < Duration::from_secs(400),
            "the run took too long"
        );
    }
    ev_thread.join().unwrap();
    let done = recorder.wait_with_output().unwrap();
    let stderr = err_thread.join().unwrap();
    let stdout = String::from_utf8_lossy(&done.stdout).into_owned();
    assert!(done.status.success(), "{stdout}{stderr}");
    assert!(browser_done);

    // The stream: ≥ 10 events/s while the samples came, the phases in order, a trace on the
    // circle. (After the record stops by itself the state changes only when a diagnosis is
    // done, which takes tens of seconds in a debug build on a loaded machine: those seconds
    // say nothing about the page's updates.)
    let samples = |v: &serde_json::Value| v["counts"]["samples"].as_u64().unwrap_or(0);
    let total = samples(&events.last().unwrap().1);
    let last_new = events
        .iter()
        .position(|(_, v)| samples(v) == total)
        .unwrap();
    let secs = events[last_new].0.duration_since(events[0].0).as_secs_f64();
    let per_s = last_new as f64 / secs;
    // The server carries (nearly) every publication: the versions the events carried against
    // the publications made (two within one of the stream's looks go out as one).
    let version = |v: &serde_json::Value| v["version"].as_u64().unwrap_or(0);
    let published = version(&events.last().unwrap().1) - version(&events[0].1) + 1;
    println!(
        "{} events over {:.1} s, {last_new} of them over the {secs:.1} s while samples came: \
         {per_s:.1}/s; {published} publications",
        events.len(),
        events
            .last()
            .unwrap()
            .0
            .duration_since(events[0].0)
            .as_secs_f64()
    );
    assert!(
        events.len() as f64 >= 0.8 * published as f64,
        "{} events for {published} publications",
        events.len()
    );
    assert!(per_s >= 10.0, "{per_s} events/s");
    let mut phases: Vec<String> = vec![];
    // (The first event may be the state before the first sample, without progress.)
    for (_, v) in events.iter().filter(|(_, v)| !v["progress"].is_null()) {
        let p = &v["progress"];
        let name = match p["sense"].as_str() {
            Some(s) if p["phase"] == "circle" => format!("circle {s}"),
            _ => p["phase"].as_str().unwrap().to_string(),
        };
        if phases.last() != Some(&name) {
            phases.push(name);
        }
    }
    println!("phases: {phases:?}");
    // (The feed-in and the feed-out last a few hundredths of a second: an event may or may not
    // fall in them.)
    let want = ["circle ccw", "circle cw", "done"];
    let mut it = phases.iter();
    for w in want {
        assert!(it.any(|p| p == w), "{w} not in order in {phases:?}");
    }
    let max_points = events
        .iter()
        .filter_map(|(_, v)| v["trace"]["points"].as_array().map(Vec::len))
        .max()
        .unwrap();
    assert!(max_points > 500, "{max_points} trace points");
    let last = &events.last().unwrap().1;
    // `record --plan` stops by itself after the program (before the scenario's tail); the page
    // stays up with its final state until the Ctrl-C.
    assert_eq!(last["ended"], "the plan's program ended");
    // The diagnosis while recording: once the circle's feed-out has ended, of that circle.
    let (when, first) = events
        .iter()
        .find(|(_, v)| {
            v["circle_diagnoses"]
                .as_array()
                .is_some_and(|l| !l.is_empty())
        })
        .expect("a diagnosis while recording");
    let out_at = events
        .iter()
        .find(|(_, v)| v["progress"]["phase"] == "done")
        .unwrap()
        .0;
    let c1 = &first["circle_diagnoses"][0];
    println!(
        "diagnosis while recording: {} ms of work, on the page {:.0} ms after the feed-out ended",
        c1["took_ms"],
        when.duration_since(out_at).as_secs_f64() * 1e3
    );
    assert!(browser_diagnosis_done);
    assert_eq!(c1["circle"], 1);
    assert_eq!(c1["pass"], true);
    let text = c1["text"].as_str().unwrap();
    let names: Vec<&str> = c1["effects"]
        .as_array()
        .unwrap()
        .iter()
        .map(|e| e["name"].as_str().unwrap())
        .collect();
    assert!(
        names.contains(&"backlash_x") && names.contains(&"squareness_xy"),
        "{names:?}\n{text}"
    );

    // The record is whole.
    let text = std::fs::read_to_string(&rec).unwrap();
    let rows: Vec<&str> = text
        .lines()
        .filter(|l| !l.starts_with('#') && !l.starts_with("seq,"))
        .collect();
    for (i, r) in rows.iter().enumerate() {
        let mut f = r.split(',');
        let seq: u64 = f.next().unwrap().parse().unwrap();
        let t_us: u64 = f.next().unwrap().parse().unwrap();
        assert_eq!((seq, t_us), (i as u64, 200 * i as u64), "row {i}: {r}");
    }
    // Everything up to the program's end and its 3 s at the end level; not the 45 s tail.
    assert!(rows.len() as u64 + 45 * 5_000 >= n && rows.len() as u64 <= n);
    assert_eq!(last["counts"]["samples"], rows.len() as u64);

    // The end-of-test diagnosis is `jdbb diagnose`'s, exactly.
    let diag = Command::new(jdbb_bin())
        .args(["diagnose", "--tolerance-um", "20", "--record"])
        .arg(&rec)
        .arg("--plan")
        .arg(&plan_json)
        .output()
        .unwrap();
    let diag = String::from_utf8(diag.stdout).unwrap();
    assert!(
        stdout.ends_with(&diag),
        "record:\n{stdout}\ndiagnose:\n{diag}"
    );
    assert!(
        diag.contains("backlash_x") && diag.contains("squareness_xy"),
        "{diag}"
    );
    assert_eq!(last["diagnosis"].as_str(), Some(diag.as_str()));
    println!("{stdout}");
}
