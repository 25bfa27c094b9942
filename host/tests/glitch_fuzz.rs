//! A glitch is data, not a crash (issue 28, findings 1, 8, 10): a record of a simulated test
//! with glitches, gaps and spikes injected is diagnosed (the glitches set aside, said, the rest
//! diagnosed as the clean record) or refused with a message (exit 2) — never a panic.
use std::fs;
use std::path::Path;
mod common;
use common::{jdbb_in, named, ok_in, stderr, stdout};

/// A one-circle plan and a 250 Hz record of it on a machine with 8 µm X backlash and 40 µm/m
/// XY squareness, in `dir` (`plan/plan.json`, `rec.csv`).
fn recorded(dir: &Path) {
    ok_in(
        dir,
        &[
            "plan",
            "--radius",
            "90",
            "--feed",
            "1500",
            "--centre",
            "100,50,-20",
            "--out",
            "plan",
        ],
    );
    fs::write(
        dir.join("mill.toml"),
        "[instrument]\nsample_rate_hz = 250\nnoise_um = 0.2\nstart_delay_s = 2\nseed = 3\n[effects]\nbacklash_x = 8\nsquareness_xy = 40\n",
    )
    .unwrap();
    ok_in(
        dir,
        &[
            "simulate",
            "--plan",
            "plan/plan.json",
            "--machine",
            "mill.toml",
            "-o",
            "rec.csv",
        ],
    );
}

/// The record's lines: the header part (comments and column names) and the data lines.
fn split(text: &str) -> (Vec<String>, Vec<String>) {
    let mut head = vec![];
    let mut data = vec![];
    for l in text.lines() {
        if data.is_empty() && (l.starts_with('#') || l.starts_with("seq")) {
            head.push(l.to_string());
        } else {
            data.push(l.to_string());
        }
    }
    (head, data)
}

/// Data line `l` with its D replaced by `d`.
fn with_d(l: &str, d: f64) -> String {
    let mut f: Vec<&str> = l.split(',').collect();
    let d = format!("{d:.7}");
    f[4] = &d;
    f.join(",")
}

fn d_of(l: &str) -> f64 {
    l.split(',').nth(4).unwrap().parse().unwrap()
}

fn diagnose(dir: &Path, rec: &str, json: bool) -> std::process::Output {
    let mut args = vec!["diagnose", "--record", rec, "--plan", "plan/plan.json"];
    if json {
        args.push("--json");
    }
    jdbb_in(dir, &args)
}

/// Exit 0, or 2 with a message naming the file; never a panic. A corrupted time is refused.
fn clean_exit(o: &std::process::Output, what: &str) {
    let e = stderr(o);
    assert!(
        !e.contains("panicked") && !e.contains("internal error"),
        "{what}: {e}"
    );
    match o.status.code() {
        Some(0) => assert!(
            !what.contains("t_us"),
            "{what}: a time going back was taken"
        ),
        Some(2) => assert!(
            e.contains("f.csv"),
            "{what}: exit 2 without the file's name: {e}"
        ),
        c => panic!("{what}: exit {c:?}: {e}"),
    }
}

#[test]
fn one_glitch_sample_is_set_aside_said_and_the_rest_diagnosed() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    recorded(d);
    let clean = named(&stdout(&diagnose(d, "rec.csv", true)));
    let names = |v: &[(String, f64)]| v.iter().map(|(n, _)| n.clone()).collect::<Vec<_>>();
    assert_eq!(names(&clean), ["backlash_x", "squareness_xy"], "{clean:?}");
    let (head, mut data) = split(&fs::read_to_string(d.join("rec.csv")).unwrap());
    // One sample at D = 50 mm on the circle (today: a panic in nalgebra), at 5 mm, and at
    // 0.001 mm: each the glitch.
    let k = data.len() / 2;
    for glitch in [50.0, 5.0, 0.001] {
        data[k] = with_d(&data[k], glitch);
        fs::write(
            d.join("g.csv"),
            [head.clone(), data.clone()].concat().join("\n"),
        )
        .unwrap();
        let o = diagnose(d, "g.csv", false);
        assert_eq!(o.status.code(), Some(0), "D {glitch}: {}", stderr(&o));
        let text = stdout(&o);
        let line = head.len() + k + 1;
        assert!(
            text.contains("set aside 1 glitch sample")
                && text.contains(&format!("line {line} at "))
                && text.contains("(circle 1)"),
            "{text}"
        );
        let o = diagnose(d, "g.csv", true);
        let json: serde_json::Value = serde_json::from_str(&stdout(&o)).unwrap();
        assert_eq!(json["sync"]["set_aside"]["glitch_count"], 1);
        assert_eq!(json["sync"]["set_aside"]["glitches"][0]["line"], line);
        let found = named(&stdout(&o));
        assert_eq!(names(&found), names(&clean), "{found:?}");
        for ((_, v), (_, c)) in found.iter().zip(&clean) {
            assert!((v - c).abs() < 0.02 * c.abs(), "{found:?} vs {clean:?}");
        }
    }
}

/// A small, seeded generator (xorshift64*): the cases are the same on every run.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
    }
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n as u64) as usize
    }
    fn uniform(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * (self.next() >> 11) as f64 / (1u64 << 53) as f64
    }
}

#[test]
fn glitches_gaps_and_spikes_never_panic_and_a_few_glitches_change_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    recorded(d);
    let clean = named(&stdout(&diagnose(d, "rec.csv", true)));
    let (head, data) = split(&fs::read_to_string(d.join("rec.csv")).unwrap());
    let mut rng = Rng(0x9e37_79b9_7f4a_7c15);
    for case in 0..25 {
        let mut v = data.clone();
        let kind = case % 5;
        let what = match kind {
            // A few glitches, anywhere (the dwell, the ramps, the circle), each alone or in a run
            // of up to three: the diagnosis names what the clean record names.
            0 | 1 => {
                let n = 1 + rng.below(4);
                for _ in 0..n {
                    let at = rng.below(v.len() - 3);
                    let run = 1 + rng.below(3);
                    let value = match rng.below(3) {
                        0 => rng.uniform(0.001, 85.0),
                        1 => d_of(&v[at]) + rng.uniform(-2.0, 2.0),
                        _ => rng.uniform(85.0, 99.9),
                    };
                    for line in &mut v[at..at + run] {
                        *line = with_d(line, value);
                    }
                }
                format!("case {case}: {n} glitch runs")
            }
            // A gap: samples lost (a pulled cable, a full queue).
            2 => {
                let at = rng.below(v.len());
                let len = 1 + rng.below(3000).min(v.len() - at - 1);
                v.drain(at..at + len);
                format!("case {case}: a gap of {len} samples at {at}")
            }
            // A corrupted time (a file written before the recorder marked them, or by hand).
            4 => {
                let at = 1 + rng.below(v.len() - 2);
                let t = [u64::MAX, 0, 1 << 40][rng.below(3)];
                let mut f: Vec<String> = v[at].split(',').map(str::to_string).collect();
                f[1] = t.to_string();
                v[at] = f.join(",");
                format!("case {case}: t_us {t} at {at}")
            }
            // A spike: D off by up to 3 mm for up to 200 samples.
            _ => {
                let at = rng.below(v.len() - 200);
                let len = 5 + rng.below(195);
                let h = rng.uniform(-3.0, 3.0);
                for line in &mut v[at..at + len] {
                    *line = with_d(line, d_of(line) + h);
                }
                format!("case {case}: a spike of {h:.3} mm over {len} samples at {at}")
            }
        };
        fs::write(d.join("f.csv"), [head.clone(), v].concat().join("\n")).unwrap();
        let o = diagnose(d, "f.csv", true);
        clean_exit(&o, &what);
        if kind < 2 {
            assert_eq!(o.status.code(), Some(0), "{what}: {}", stderr(&o));
            let found = named(&stdout(&o));
            let names = |v: &[(String, f64)]| v.iter().map(|(n, _)| n.clone()).collect::<Vec<_>>();
            assert_eq!(
                names(&found),
                names(&clean),
                "{what}: {found:?} vs {clean:?}"
            );
            for ((_, v), (_, c)) in found.iter().zip(&clean) {
                assert!(
                    (v - c).abs() < 0.05 * c.abs(),
                    "{what}: {found:?} vs {clean:?}"
                );
            }
        }
    }
}

/// The numbers of a JSON value, flattened in order.
fn numbers(v: &serde_json::Value, out: &mut Vec<f64>) {
    match v {
        serde_json::Value::Number(n) => out.push(n.as_f64().unwrap()),
        serde_json::Value::Array(a) => a.iter().for_each(|x| numbers(x, out)),
        serde_json::Value::Object(m) => m.values().for_each(|x| numbers(x, out)),
        _ => {}
    }
}

#[test]
fn calibrate_record_sets_a_glitch_aside_and_calibrates_the_rest() {
    // Issue 28 (1): one sample at D = 50 mm made `calibrate --record --plan` panic in nalgebra.
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    ok_in(
        d,
        &[
            "plan",
            "--calibration-test",
            "--centre",
            "100,50,-20",
            "--feed",
            "2000",
            "--distance",
            "85",
            "--distance",
            "97",
            "--out",
            "cal",
        ],
    );
    fs::write(
        d.join("inst.toml"),
        "[instrument]\nsample_rate_hz = 250\nnoise_um = 0.2\nstart_delay_s = 2\nseed = 3\n",
    )
    .unwrap();
    ok_in(
        d,
        &[
            "simulate",
            "--plan",
            "cal/plan.json",
            "--machine",
            "inst.toml",
            "-o",
            "rec.csv",
        ],
    );
    let calibrate = |rec: &str| {
        jdbb_in(
            d,
            &[
                "calibrate",
                "--record",
                rec,
                "--plan",
                "cal/plan.json",
                "--json",
            ],
        )
    };
    let clean = calibrate("rec.csv");
    assert!(clean.status.success(), "{}", stderr(&clean));
    let (head, mut data) = split(&fs::read_to_string(d.join("rec.csv")).unwrap());
    let k = data.len() / 2;
    data[k] = with_d(&data[k], 50.0);
    fs::write(d.join("g.csv"), [head.clone(), data].concat().join("\n")).unwrap();
    let glitched = calibrate("g.csv");
    let e = stderr(&glitched);
    assert_eq!(glitched.status.code(), Some(0), "{e}");
    assert!(
        e.contains("set aside 1 glitch sample")
            && e.contains(&format!("line {} at ", head.len() + k + 1)),
        "{e}"
    );
    let cal = |o: &std::process::Output| {
        let v: serde_json::Value = serde_json::from_str(&stdout(o)).unwrap();
        let mut n = vec![];
        numbers(&v["calibration"], &mut n);
        n
    };
    let (a, b) = (cal(&clean), cal(&glitched));
    assert_eq!(a.len(), b.len());
    for (x, y) in a.iter().zip(&b) {
        assert!((x - y).abs() <= 1e-6 + 1e-3 * x.abs(), "{a:?} vs {b:?}");
    }
}
