//! Every reader driven with generated garbage (proptest, fixed seed and case count): random
//! bytes, and valid files with random edits (characters replaced, lines cut or doubled, numbers
//! made absurd). Each must answer bad input (exit code 2) with a location `file:line[:col]`, or
//! read the file; never panic. The frames reader (the link's decoder) must account for every
//! byte without panicking, and what `record` writes from any frames must read back.
//!
//! Readers: CSV samples (`diagnose --samples`), record CSV (`diagnose --record`, `recompute`),
//! plan.json, calibration TOML, machine TOML (`simulate --machine`), diagnosis JSON, the controllers' `--current` files, frames.
use std::io::{Read, Write};
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::atomic::AtomicBool;
use std::sync::OnceLock;

use jdbb::Error;
use proptest::prelude::*;
use proptest::test_runner::{Config, RngAlgorithm, TestCaseError, TestRng, TestRunner};

const CASES: u32 = 300;

/// A runner with a fixed seed: the same cases on every run.
fn runner() -> TestRunner {
    let config = Config {
        cases: CASES,
        failure_persistence: None,
        rng_algorithm: RngAlgorithm::ChaCha,
        ..Config::default()
    };
    TestRunner::new_with_rng(config, TestRng::from_seed(RngAlgorithm::ChaCha, &[16; 32]))
}

/// Tokens a careless edit puts in.
const TOKENS: &[&str] = &[
    "nan",
    "inf",
    "-inf",
    "1e309",
    "-1e300",
    "1e-300",
    "0",
    "-0",
    "",
    ",",
    ",,",
    "\n",
    "\r\n",
    "\"",
    "{",
    "}",
    "[",
    "]",
    ":",
    "=",
    "#",
    "x",
    "\u{feff}",
    "\u{ff}",
    "9999999999999999999999",
    "-",
    ".",
    "1.2.3",
    "true",
    "null",
    "[enc1]",
    "l1_mm = ",
    "\"kind\": \"arc\"",
    "\t",
];

/// `base` with `edits` applied: (position, what, token): replace a byte with a token, delete a
/// span, duplicate a span, cut the text there, or insert a token.
fn mutate(base: &[u8], edits: &[(usize, u8, usize)]) -> Vec<u8> {
    let mut v = base.to_vec();
    for &(pos, what, tok) in edits {
        if v.is_empty() {
            v.extend_from_slice(TOKENS[tok % TOKENS.len()].as_bytes());
            continue;
        }
        let p = pos % v.len();
        let t = TOKENS[tok % TOKENS.len()].as_bytes();
        match what % 5 {
            0 => {
                v.splice(p..p + 1, t.iter().copied());
            }
            1 => {
                let end = (p + 1 + tok % 40).min(v.len());
                v.drain(p..end);
            }
            2 => {
                let end = (p + 1 + tok % 200).min(v.len());
                let span = v[p..end].to_vec();
                v.splice(p..p, span);
            }
            3 => v.truncate(p),
            _ => {
                v.splice(p..p, t.iter().copied());
            }
        }
    }
    v
}

/// Garbage for a reader whose valid input is `base`: random bytes or a mutated `base`.
fn garbage(base: &'static [u8]) -> impl Strategy<Value = Vec<u8>> {
    prop_oneof![
        1 => proptest::collection::vec(any::<u8>(), 0..600),
        4 => proptest::collection::vec((any::<usize>(), any::<u8>(), any::<usize>()), 1..6)
            .prop_map(move |edits| mutate(base, &edits)),
    ]
}

/// The result of reading must be success or bad input (exit 2) whose message starts with the
/// file's name and a line number (`name:LINE:` or `name:LINE:COL:`).
fn check<T>(name: &str, r: jdbb::Result<T>) -> Result<(), TestCaseError> {
    if let Err(e) = r {
        let msg = e.to_string();
        prop_assert_eq!(e.exit_code(), 2, "{}", msg);
        let rest = msg.strip_prefix(name).and_then(|r| r.strip_prefix(':'));
        let line_ok = rest.is_some_and(|r| {
            let digits = r.chars().take_while(char::is_ascii_digit).count();
            digits > 0 && r[digits..].starts_with(':')
        });
        prop_assert!(
            line_ok || matches!(e, Error::InputFile { .. }),
            "no location in `{}`",
            msg
        );
    }
    Ok(())
}

/// A ccw then cw circle of radius 50 mm, 40 samples each way (`diagnose --samples` reads it).
fn samples_text() -> &'static str {
    static T: OnceLock<String> = OnceLock::new();
    T.get_or_init(|| {
        let mut s = String::from("t_s,x_mm,y_mm,z_mm,d_mm\n");
        for i in 0..80 {
            let k = if i < 40 { i } else { 80 - i };
            let a = (k as f64 * 9.0).to_radians();
            s += &format!(
                "{},{:.4},{:.4},0,{:.6}\n",
                i as f64 * 0.1,
                50.0 * a.cos(),
                50.0 * a.sin(),
                50.0 + 0.001 * (2.0 * a).cos()
            );
        }
        s
    })
}

const RECORD: &str = "seq,t_us,enc1,enc2,d_mm\n0,0,1000,-2000,99.9000000\n1,100,1001,-2003,99.9000010\n2,200,1002,-2006,99.9000020\n3,300,1003,-2009,99.9000030\n";

const CAL_TOML: &str = "# fitted\nl1_mm = 50.0\nl2_mm = 50.0\naxes_skew_rad = 1e-5\n[enc1]\ncounts_per_rev = 8388608\nzero_count = 12\ndirection = \"Positive\"\neccentricity_rad = 1e-4\n[enc2]\ncounts_per_rev = 8388608\nzero_count = -7\ndirection = \"Negative\"\n[frame1]\ntilt_rad = 1e-4\n";

const CURRENT: &[(&str, &str)] = &[
    (
        "linuxcnc",
        "[JOINT_0]\nBACKLASH = 0.010\n[JOINT_1]\nBACKLASH = 0.004\n",
    ),
    ("grblhal", "$100=800.0\n$101=800.0\n$160=0.010\n"),
    (
        "marlin",
        "echo:  M92 X80.00 Y80.00 Z400.00\nM425 F1.00 X0.01 Y0.02\nM852 I0.0001\n",
    ),
    (
        "klipper",
        "[stepper_x]\nrotation_distance: 40\n[skew_correction]\n",
    ),
    (
        "fanuc",
        "%\nN01001P00000000\nN01013A1P00000010A2P00000010\nN01851 A1 P12 A2 P8\nN03620A1P40\nN10040P-2\n%\n",
    ),
    (
        "sinumerik",
        "$MN_SCALING_SYSTEM_IS_METRIC=1\n$MA_BACKLASH[0,AX1]=0.012\n$AA_ENC_COMP[0,3,AX2]=0.001\n",
    ),
    ("heidenhain", "MP710.0:+0.0120\nMP720.1:-0.0100\n"),
];

/// plan.json and a diagnosis JSON written by the program itself, once.
fn program_outputs() -> &'static (String, String) {
    static T: OnceLock<(String, String)> = OnceLock::new();
    T.get_or_init(|| {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let bin = env!("CARGO_BIN_EXE_jdbb");
        let ok = |args: &[&str]| {
            let o = Command::new(bin)
                .current_dir(d)
                .args(args)
                .output()
                .unwrap();
            assert!(
                o.status.success(),
                "{args:?}: {}",
                String::from_utf8_lossy(&o.stderr)
            );
            String::from_utf8(o.stdout).unwrap()
        };
        ok(&[
            "plan", "--radius", "90", "--feed", "1000", "--centre", "0,0,0", "--out", "p",
        ]);
        ok(&[
            "simulate",
            "--rate",
            "50",
            "--effect",
            "backlash_x=4",
            "--effect",
            "scale_y=20",
            "-o",
            "s.csv",
        ]);
        let diag = ok(&["diagnose", "--samples", "s.csv", "--json", "--machine", "m"]);
        (
            std::fs::read_to_string(d.join("p/plan.json")).unwrap(),
            diag,
        )
    })
}

fn leak(s: &str) -> &'static [u8] {
    Box::leak(s.to_string().into_boxed_str()).as_bytes()
}

/// Run `read` on garbage made from `base`, written to a file `name` in a temporary directory.
fn fuzz_file<T>(name: &'static str, base: &'static [u8], read: impl Fn(&Path) -> jdbb::Result<T>) {
    let dir = tempfile::tempdir().unwrap();
    let path: PathBuf = dir.path().join(name);
    runner()
        .run(&garbage(base), |bytes| {
            std::fs::write(&path, &bytes).unwrap();
            check(&path.display().to_string(), read(&path))
        })
        .unwrap();
}

#[test]
fn csv_samples() {
    fuzz_file("s.csv", leak(samples_text()), |p| {
        jdbb::diagnose::input::read_samples(p, [None; 3])
    });
}

#[test]
fn record_csv() {
    fuzz_file("rec.csv", RECORD.as_bytes(), |p| {
        jdbb::sync::Record::read(p)
    });
    // recompute reads a record too (and writes only a complete output).
    let cal = jdbb_core::calib::Calibration::DEFAULT;
    let out_dir = tempfile::tempdir().unwrap();
    fuzz_file("rec2.csv", RECORD.as_bytes(), |p| {
        let out = out_dir.path().join("o.csv");
        let _ = std::fs::remove_file(&out);
        jdbb::instrument::recompute::recompute(p, &cal, &out, true)
    });
}

#[test]
fn plan_json() {
    fuzz_file("plan.json", leak(&program_outputs().0), |p| {
        jdbb::plan::Plan::read(p)
    });
}

#[test]
fn calibration_toml() {
    fuzz_file("cal.toml", CAL_TOML.as_bytes(), |p| {
        jdbb::instrument::file::read_calibration(p)
    });
}

#[test]
fn machine_toml() {
    // The example `jdbb simulate --machine` prints (every key, and the list of every effect).
    fuzz_file(
        "m.toml",
        leak(&jdbb::simulate::machine::example()),
        jdbb::simulate::machine::Machine::read,
    );
}

#[test]
fn diagnosis_json() {
    fuzz_file("diag.json", leak(&program_outputs().1), |p| {
        jdbb::report::document::DiagnosisDoc::read(p)
    });
}

#[test]
fn controller_settings() {
    for (name, text) in CURRENT {
        let c = jdbb::compensate::Controller::parse(name).unwrap();
        fuzz_file("current.txt", text.as_bytes(), move |p| {
            jdbb::compensate::current::Current::read(p, c)
        });
    }
}

/// A port that plays back `data` and swallows what is written to it.
struct Playback(std::io::Cursor<Vec<u8>>);

impl Read for Playback {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let n = buf.len().min(97);
        self.0.read(&mut buf[..n])
    }
}

impl Write for Playback {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        Ok(buf.len())
    }
    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

/// A file in memory that `record` can cut back.
struct MemFile(std::io::Cursor<Vec<u8>>);

impl Write for MemFile {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.0.write(buf)
    }
    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

impl jdbb::link::record::Truncate for MemFile {
    fn truncate_to(&mut self, len: u64) -> std::io::Result<()> {
        self.0.get_mut().truncate(len as usize);
        self.0.set_position(len);
        Ok(())
    }
}

/// Frames: valid sample batches (any numbers in them, NaN and time going back included) mixed
/// with random bytes and cut frames. The decoder accounts for them without a panic, and the CSV
/// `record` writes from them reads back through the one CSV reader: every data line is a sample
/// with a finite positive D and increasing time; the rest are `# suspect` lines.
#[test]
fn frames() {
    use jdbb_core::protocol::{
        self, DeviceMsg, Sample, SampleBatch, Status, BATCH_LEN, MAX_FRAME_LEN,
    };
    // Mostly a plausible sample (time on, D in range, counts within a turn), now and then
    // anything: NaN, infinities, negative D, time going back, counts far out.
    let sample = prop_oneof![
        4 => (0u64..100, -4_000_000i64..4_000_000, -4_000_000i64..4_000_000, 60.0f64..99.0)
            .prop_map(|(dt, e1, e2, d)| (dt, e1, e2, d, true)),
        1 => (any::<u64>(), any::<i64>(), any::<i64>(), any::<f64>())
            .prop_map(|(t, e1, e2, d)| (t, e1, e2, d, false)),
    ];
    let piece = prop_oneof![
        proptest::collection::vec(any::<u8>(), 0..64).prop_map(|b| (None, b)),
        (
            any::<u32>(),
            proptest::collection::vec(sample, BATCH_LEN..=BATCH_LEN),
            any::<u8>()
        )
            .prop_map(|(seq, xs, cut)| {
                let mut samples = heapless::Vec::new();
                for (k, (t_us, enc1, enc2, d_mm, on_time)) in xs.into_iter().enumerate() {
                    let t_us = if on_time {
                        u64::from(seq % 1000) * 2000 + 100 * k as u64 + t_us % 50
                    } else {
                        t_us % 1_000_000_000
                    };
                    let _ = samples.push(Sample {
                        t_us,
                        enc1: enc1 % 20_000_000,
                        enc2,
                        d_mm,
                        status: Status(0),
                    });
                }
                let msg = DeviceMsg::Batch(SampleBatch {
                    seq: seq % 1000,
                    dropped: 0,
                    samples,
                });
                let mut buf = [0u8; MAX_FRAME_LEN];
                let f = protocol::encode(&msg, &mut buf).unwrap().to_vec();
                // Now and then a frame cut short.
                let keep = if cut < 40 {
                    f.len() * usize::from(cut) / 40
                } else {
                    f.len()
                };
                (Some(()), f[..keep].to_vec())
            }),
    ];
    let dir = tempfile::tempdir().unwrap();
    let csv_path = dir.path().join("rec.csv");
    let (data_lines, suspect_lines) = (std::cell::Cell::new(0usize), std::cell::Cell::new(0usize));
    runner()
        .run(&proptest::collection::vec(piece, 1..12), |pieces| {
            let bytes: Vec<u8> = pieces.into_iter().flat_map(|(_, b)| b).collect();
            let n = bytes.len() as u64;
            // Every byte read is accounted for.
            let mut plain = jdbb::link::stream::Stream::new(
                Playback(std::io::Cursor::new(bytes.clone())),
                "fuzz",
            );
            let mut samples = 0u64;
            while plain
                .poll(|b| samples += b.len() as u64)
                .map_err(|e| TestCaseError::fail(e.to_string()))?
                != jdbb::link::stream::Poll::Closed
            {}
            prop_assert_eq!(plain.stats().bytes, n);
            prop_assert_eq!(plain.stats().samples, samples);
            // What a record of them writes reads back.
            let mut stream =
                jdbb::link::stream::Stream::new(Playback(std::io::Cursor::new(bytes)), "fuzz");
            let mut file = std::io::Cursor::new(jdbb::link::record::CSV_HEADER.as_bytes().to_vec());
            file.set_position(jdbb::link::record::CSV_HEADER.len() as u64);
            let mut out = jdbb::link::record::CsvOut::new(
                MemFile(file),
                jdbb::link::record::CSV_HEADER.len() as u64,
            );
            let _ = jdbb::link::record::record_to(
                &mut stream,
                &mut out,
                &csv_path,
                None,
                &AtomicBool::new(false),
                &mut |_| {},
            );
            let text = String::from_utf8(out.file.0.into_inner()).unwrap();
            std::fs::write(&csv_path, &text).unwrap();
            suspect_lines.set(suspect_lines.get() + text.matches("\n# suspect:").count());
            data_lines
                .set(data_lines.get() + text.lines().filter(|l| !l.starts_with('#')).count() - 1);
            let mut t = jdbb::table::Table::open(&csv_path).unwrap();
            let c = t.require(&["seq", "t_us", "enc1", "enc2", "d_mm"]).unwrap();
            let mut last_t = None;
            while let Some(row) = t
                .next_row()
                .map_err(|e| TestCaseError::fail(e.to_string()))?
            {
                let d = row
                    .number(&c[4])
                    .map_err(|e| TestCaseError::fail(e.to_string()))?;
                let t_us = row
                    .integer(&c[1])
                    .map_err(|e| TestCaseError::fail(e.to_string()))?;
                prop_assert!(d > 0.0 && d.is_finite(), "{}", d);
                prop_assert!(
                    last_t.is_none_or(|l| t_us > l),
                    "time {} after {:?}",
                    t_us,
                    last_t
                );
                last_t = Some(t_us);
            }
            Ok(())
        })
        .unwrap();
    // The generated frames did reach the file, as data and as suspects.
    assert!(
        data_lines.get() > 100 && suspect_lines.get() > 100,
        "data lines {}, suspect lines {}",
        data_lines.get(),
        suspect_lines.get()
    );
}

/// The same readers through the command line: exit 2 with a location, never 101.
#[test]
fn command_line() {
    let bin = env!("CARGO_BIN_EXE_jdbb");
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(d.join("rec.csv"), RECORD).unwrap();
    std::fs::write(d.join("cal.toml"), CAL_TOML).unwrap();
    std::fs::write(d.join("plan.json"), &program_outputs().0).unwrap();
    let cases: Vec<(&str, &'static [u8], Vec<&str>)> = vec![
        (
            "g.csv",
            leak(samples_text()),
            vec!["diagnose", "--samples", "g.csv"],
        ),
        (
            "g.csv",
            RECORD.as_bytes(),
            vec!["diagnose", "--record", "g.csv", "--plan", "plan.json"],
        ),
        (
            "g.json",
            leak(&program_outputs().0),
            vec!["diagnose", "--record", "rec.csv", "--plan", "g.json"],
        ),
        (
            "g.toml",
            CAL_TOML.as_bytes(),
            vec![
                "recompute",
                "--record",
                "rec.csv",
                "--calibration",
                "g.toml",
                "-o",
                "o.csv",
                "--force",
            ],
        ),
        (
            "g.json",
            leak(&program_outputs().1),
            vec![
                "compensate",
                "--diagnosis",
                "g.json",
                "--controller",
                "grblhal",
            ],
        ),
    ];
    for (file, base, args) in cases {
        let mut r = TestRunner::new_with_rng(
            Config {
                cases: 24,
                failure_persistence: None,
                ..Config::default()
            },
            TestRng::from_seed(RngAlgorithm::ChaCha, &[61; 32]),
        );
        r.run(&garbage(base), |bytes| {
            std::fs::write(d.join(file), &bytes).unwrap();
            let o = Command::new(bin)
                .current_dir(d)
                .args(&args)
                .output()
                .unwrap();
            let e = String::from_utf8_lossy(&o.stderr);
            prop_assert!(
                o.status.code() == Some(2) || o.status.success(),
                "{:?}: {}",
                args,
                e
            );
            if !o.status.success() {
                prop_assert!(!e.contains("panicked"), "{}", e);
                let located = e.lines().next().is_some_and(|l| {
                    l.strip_prefix("error: ").is_some_and(|l| {
                        l.contains(&format!("{file}:")) || l.starts_with("cannot read")
                    })
                });
                prop_assert!(located, "{:?}: no location in `{}`", args, e);
            }
            Ok(())
        })
        .unwrap();
    }
}
