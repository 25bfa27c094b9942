//! The live page's cost (issue 18 §5): (1) what the feed costs the recorder — following the plan
//! and publishing the state with its trace 25 times a second — for a 5 kHz test, as a share of one
//! core; (2) how long the diagnosis while recording takes for one circle at 5 kHz, from its last
//! sample (the worker's synchronisation and diagnosis).
//!
//! Run: `cargo bench -p jdbb --bench live` (release profile). Goals: (1) < 5 % of a core,
//! (2) ≤ 200 ms.
use std::time::{Duration, Instant};

use jdbb::circular::plan::build::{plan, PlanSpec};
use jdbb::circular::plan::{Dialect, Plan, Plane, Segment};
use jdbb::link::stream::{SeqSample, Stats};
use jdbb::live_web::feed::{new_board, LiveFeed};
use jdbb::live_web::worker::Diagnoser;
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

fn main() {
    let spec = PlanSpec::machine_test(
        &[90.0],
        &[0.0],
        Plane::Xy,
        4000.0,
        [0.0, 0.0, 0.0],
        Dialect::Linuxcnc,
    );
    let plan = plan(&spec, &jdbb_core::calib::Calibration::DEFAULT).expect("the plan");
    let d = synthetic(&plan);
    let device_s = d.len() as f64 / RATE_HZ;

    // (1) The feed, batches of 50 samples (10 ms at 5 kHz, a read of the recorder), the clock
    // the feed sees advancing with the device's time so that it publishes every 40 ms.
    let board = new_board();
    let mut feed = LiveFeed::new(board.clone(), Some(&plan), None);
    let mut stats = Stats::default();
    let base = Instant::now();
    let t0 = Instant::now();
    for (b, chunk) in d.chunks(50).enumerate() {
        let batch: Vec<SeqSample> = chunk
            .iter()
            .enumerate()
            .map(|(i, &d_mm)| {
                let seq = (b * 50 + i) as u64;
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
            .collect();
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

    // (2) The diagnosis while recording of the circle, from its last sample.
    let w = Diagnoser::start(&plan, Some(20.0));
    let t_s: Vec<f64> = (0..d.len()).map(|i| i as f64 / RATE_HZ).collect();
    let end_s = t_s[t_s.len() - 1] - 0.9;
    w.circle_done(1, end_s);
    let t0 = Instant::now();
    w.samples(t_s.iter().copied().zip(d.iter().copied()).collect());
    let r = loop {
        if let Some(r) = w.result() {
            break r;
        }
        std::thread::sleep(Duration::from_millis(1));
    };
    println!(
        "diagnosis of circle 1 ({} samples at 5 kHz): {:.0} ms of work, {:.0} ms from the last sample (goal ≤ 200 ms); {}",
        d.len(),
        r.took_ms,
        t0.elapsed().as_secs_f64() * 1e3,
        r.text.lines().next().unwrap_or("")
    );

    // Where the time goes: the same steps, timed one by one.
    let rec = jdbb::circular::sync::Record::from_samples(std::path::Path::new("bench"), t_s, d);
    let t = Instant::now();
    let sync = jdbb::circular::sync::synchronise(&plan, &rec).expect("synchronised");
    let t_sync = t.elapsed();
    let t = Instant::now();
    let (path, dd) =
        jdbb::circular::sync::data_path(&plan, &rec, &sync, [None; 3]).expect("the data path");
    let t_path = t.elapsed();
    let t = Instant::now();
    let diag =
        jdbb::circular::diagnose::diagnose(&path, &dd, &Default::default()).expect("diagnosed");
    println!(
        "  synchronise {:.0} ms, data path {:.0} ms, diagnose {:.0} ms ({} data samples)",
        t_sync.as_secs_f64() * 1e3,
        t_path.as_secs_f64() * 1e3,
        t.elapsed().as_secs_f64() * 1e3,
        diag.samples
    );
}
