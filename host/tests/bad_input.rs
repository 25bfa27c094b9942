//! What a user who tries to break the command line meets: every case here once panicked, ran
//! without bound, or answered absurd input with exit 0. Bad input exits 2 with a message that
//! names the problem (and its limit); a runtime failure exits 1; nothing panics (exit 101).
use std::path::{Path, PathBuf};
use std::process::Stdio;
use std::time::{Duration, Instant};
mod common;
use common::{command, jdbb};

/// `args` fail with exit `code`, stderr containing `want`, and no panic.
fn fails(args: &[&str], code: i32, want: &str) -> String {
    let t0 = Instant::now();
    let o = jdbb(args);
    let err = String::from_utf8_lossy(&o.stderr).to_string();
    assert_eq!(o.status.code(), Some(code), "{args:?}: {err}");
    assert!(err.contains(want), "{args:?}: wanted `{want}` in `{err}`");
    assert!(!err.contains("panicked"), "{args:?}: {err}");
    // A hang, not a speed check (a debug build on busy cores): bad input is refused, not chewed.
    assert!(
        t0.elapsed() < Duration::from_secs(120),
        "{args:?} took {:?}",
        t0.elapsed()
    );
    err
}

fn data(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../data")
        .join(name)
}

/// A ccw then cw circle of radius 50 mm, 720 samples each way: a file `diagnose` accepts.
fn circle_csv() -> String {
    let mut s = String::from("t_s,x_mm,y_mm,z_mm,d_mm\n");
    for i in 0..1440 {
        let k = if i < 720 { i } else { 1440 - i };
        let a = (k as f64 * 0.5).to_radians();
        s += &format!(
            "{},{},{},0,{}\n",
            i as f64 * 0.01,
            50.0 * a.cos(),
            50.0 * a.sin(),
            50.0 + 0.001 * (3.0 * a).sin()
        );
    }
    s
}

fn write(dir: &Path, name: &str, bytes: &[u8]) -> String {
    let p = dir.join(name);
    std::fs::write(&p, bytes).unwrap();
    p.to_str().unwrap().to_string()
}

#[test]
fn durations_that_cannot_be_meant_are_refused() {
    for cmd in ["live", "record"] {
        for s in ["1e300", "1e19", "nan", "-1"] {
            let seconds = format!("--seconds={s}");
            let mut args = vec![cmd, "--port", "/dev/null", seconds.as_str()];
            if cmd == "record" {
                args.extend(["--out", "/tmp/never-written.csv"]);
            }
            fails(&args, 2, "--seconds");
        }
    }
    fails(
        &["live", "--port", "/dev/null", "--seconds", "1e300"],
        2,
        "more than a year",
    );
}

#[test]
fn simulations_that_cannot_be_meant_are_refused_with_the_limit() {
    fails(&["simulate", "--sigma-um", "inf"], 2, "--sigma-um");
    fails(&["simulate", "--rate", "inf"], 2, "--rate");
    fails(&["simulate", "--rate", "1e12"], 2, "at most 1000000 Hz");
    fails(&["simulate", "--feed", "1e-12"], 2, "0.1 to 100000 mm/min");
    fails(&["simulate", "--radius", "1e300"], 2, "(0, 10000] mm");
    fails(
        &[
            "simulate", "--radius", "9000", "--feed", "1", "--rate", "100000",
        ],
        2,
        "at most 5000000",
    );
}

#[test]
fn a_closed_pipe_or_a_full_disk_does_not_panic() {
    let dir = tempfile::tempdir().unwrap();
    let f = write(dir.path(), "c.csv", circle_csv().as_bytes());
    // `jdbb diagnose ... | true`: the reader is gone before anything is written.
    let (reader, writer) = std::io::pipe().unwrap();
    drop(reader);
    let o = command()
        .args(["diagnose", "--samples", &f])
        .stdout(Stdio::from(writer))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!err.contains("panicked"), "{err}");
    assert_eq!(o.status.code(), Some(0), "{err}");
    // `> /dev/full`: a real write failure, exit 1, named.
    if Path::new("/dev/full").exists() {
        for args in [vec!["diagnose", "--samples", f.as_str()], vec!["devices"]] {
            let full = std::fs::OpenOptions::new()
                .write(true)
                .open("/dev/full")
                .unwrap();
            let o = command().args(&args).stdout(full).output().unwrap();
            let err = String::from_utf8_lossy(&o.stderr);
            assert_eq!(o.status.code(), Some(1), "{args:?}: {err}");
            assert!(err.contains("cannot write to standard output"), "{err}");
            assert!(!err.contains("panicked"), "{err}");
        }
    }
}

#[test]
fn rotary_order_is_bounded_by_the_angles() {
    let t = data("dbb_c_turntable_table1.csv");
    let t = t.to_str().unwrap();
    fails(
        &["rotary", "--axis", "c", "--table", t, "--order", "1000"],
        2,
        "up to order 8",
    );
    fails(
        &["rotary", "--axis", "c", "--table", t, "--l1", "nan"],
        2,
        "--l1",
    );
    assert!(
        jdbb(&["rotary", "--axis", "c", "--table", t, "--order", "8"])
            .status
            .success()
    );
}

#[test]
fn absurd_inputs_are_bad_input() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let header = "t_s,x_mm,y_mm,z_mm,d_mm\n";
    let rows = |f: &dyn Fn(usize) -> String| -> String {
        std::iter::once(header.to_string())
            .chain((0..400).map(f))
            .collect()
    };
    // All-zero, stationary and straight-line paths; a negative D.
    let zero = write(
        d,
        "zero.csv",
        rows(&|i| format!("{i},0,0,0,50\n")).as_bytes(),
    );
    fails(&["diagnose", "--samples", &zero], 2, "at the table ball");
    let still = write(
        d,
        "still.csv",
        rows(&|i| format!("{i},50,0,0,50\n")).as_bytes(),
    );
    fails(&["diagnose", "--samples", &still], 2, "moves no axis");
    let line = write(
        d,
        "line.csv",
        rows(&|i| {
            let (x, y) = (i as f64 * 0.1 - 20.0, 30.0 + 0.05 * i as f64);
            format!("{i},{x},{y},0,{}\n", x.hypot(y))
        })
        .as_bytes(),
    );
    fails(
        &["diagnose", "--samples", &line],
        2,
        "arcs of at least 180°",
    );
    let neg = circle_csv().replacen(",50.", ",-50.", 1);
    let neg = write(d, "neg.csv", neg.as_bytes());
    fails(&["diagnose", "--samples", &neg], 2, "d_mm is -50");
    // Identical angles for diagnose-rotary, as `rotary` refuses them.
    let same: String = std::iter::once("angle_deg,dl1_radial_mm\n".to_string())
        .chain((0..19).map(|i| format!("20,{}\n", i as f64 * 1e-3)))
        .collect();
    let same = write(d, "same.csv", same.as_bytes());
    fails(
        &["diagnose-rotary", "--samples", &same],
        2,
        "distinct angles",
    );
    fails(
        &["rotary", "--axis", "c", "--table", &same],
        2,
        "distinct angles",
    );
    // rrsps: a bar of 1e300 mm, a NaN angle.
    let p = data("rrsps_parameters_table2_3.csv");
    let p = p.to_str().unwrap();
    let huge: String = std::iter::once("theta_a_deg,theta_c_deg,d_mm\n".to_string())
        .chain((0..50).map(|i| format!("{},{},1e300\n", -i as f64, 7.0 * i as f64)))
        .collect();
    let huge = write(d, "huge.csv", huge.as_bytes());
    fails(
        &[
            "rrsps",
            "identify",
            "--samples",
            &huge,
            "--design",
            p,
            "--case",
            "M1",
        ],
        2,
        "must be a bar length",
    );
    fails(
        &[
            "rrsps",
            "design",
            "--params",
            p,
            "--case",
            "M1",
            "--d",
            "300",
            "--require-a=nan,0",
        ],
        2,
        "not a finite number",
    );
    // NaN and repeated options.
    let c = write(d, "c.csv", circle_csv().as_bytes());
    fails(
        &[
            "diagnose",
            "--record",
            &c,
            "--path",
            &c,
            "--path-offset-s",
            "nan",
        ],
        2,
        "--path-offset-s",
    );
    fails(
        &["diagnose", "--samples", &c, "--pitch", "x=10,x=20"],
        2,
        "given twice",
    );
}

#[test]
fn files_are_read_by_the_same_rules_everywhere() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // Excel's "CSV UTF-8": a byte-order mark and CRLF.
    let excel = format!("\u{feff}{}", circle_csv().replace('\n', "\r\n"));
    let excel = write(d, "excel.csv", excel.as_bytes());
    let o = jdbb(&["diagnose", "--samples", &excel, "--json"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    // Not UTF-8: exit 2 at the line and column.
    let mut bytes = circle_csv().into_bytes();
    let line_start = bytes.iter().position(|&b| b == b'\n').unwrap() + 1;
    bytes[line_start + 2] = 0xff;
    let latin = write(d, "latin.csv", &bytes);
    fails(
        &["diagnose", "--samples", &latin],
        2,
        "latin.csv:2:3: not UTF-8 text (byte 0xff)",
    );
    // A second d_mm column.
    let two = circle_csv().replacen("d_mm\n", "d_mm,d_mm\n", 1);
    let two = write(d, "two.csv", two.as_bytes());
    fails(
        &["diagnose", "--samples", &two],
        2,
        "column `d_mm` appears twice",
    );
    // A 500 kB bad field is not echoed whole.
    let long = format!(
        "{}{}\n",
        "t_s,x_mm,y_mm,z_mm,d_mm\n0,1,2,3,",
        "9".repeat(500_000) + "x"
    );
    let long = write(d, "long.csv", long.as_bytes());
    let err = fails(&["diagnose", "--samples", &long], 2, "characters)");
    assert!(err.len() < 1000, "{} bytes of error", err.len());
    // A 5 MB line is not a table row: refused at the line limit, named, not read whole.
    let longer = format!(
        "{}{}\n",
        "t_s,x_mm,y_mm,z_mm,d_mm\n0,1,2,3,",
        "9".repeat(5 << 20)
    );
    let longer = write(d, "longer.csv", longer.as_bytes());
    let err = fails(
        &["diagnose", "--samples", &longer],
        2,
        "longer.csv:2: a line longer than 1 MiB",
    );
    assert!(err.len() < 1000, "{} bytes of error", err.len());
    // A missing file: exit 2, its cause once.
    let err = fails(
        &["diagnose-rotary", "--samples", "/nonexistent/nope.csv"],
        2,
        "nope.csv",
    );
    assert_eq!(err.matches("No such file or directory").count(), 1, "{err}");
}

#[test]
fn calibrate_and_recompute_refuse_bad_input() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // CAL.csv: a missing column, a count that is no integer, too few samples, counts of another
    // instrument (90° from the zero).
    let cal = write(d, "cal.csv", b"enc1,enc2\n1,2\n");
    fails(
        &["calibrate", "--samples", &cal],
        2,
        "cal.csv:1: missing column `d_ref_mm`",
    );
    let cal = write(d, "cal.csv", b"enc1,enc2,d_ref_mm\n1,2.5,99\n");
    fails(
        &["calibrate", "--samples", &cal],
        2,
        "cal.csv:2:3: enc2: `2.5` is not an integer",
    );
    let cal = write(d, "cal.csv", b"enc1,enc2,d_ref_mm\n1,2,99.9\n");
    fails(&["calibrate", "--samples", &cal], 2, "only 1 samples");
    let mut text = String::from("enc1,enc2,d_ref_mm\n");
    for i in 0..40 {
        text += &format!("{},0,99.9\n", 2_097_152 * (i % 2));
    }
    let cal = write(d, "cal.csv", text.as_bytes());
    fails(
        &["calibrate", "--samples", &cal],
        2,
        "cal.csv:3:1: enc1 is 90.0°",
    );
    fails(
        &["calibrate", "--samples", &cal, "-o", &cal],
        2,
        "an input of this command",
    );
    let nominal = write(d, "nominal.toml", b"l1_mm = 50.0\nl2_mm = \"long\"\n");
    fails(
        &["calibrate", "--samples", &cal, "--nominal", &nominal],
        2,
        "nominal.toml:2:9:",
    );
    fails(
        &[
            "calibrate",
            "--samples",
            &data("none.csv").to_string_lossy(),
        ],
        2,
        "none.csv",
    );
    // recompute: never over the record; bad rows name file:line:column.
    let good = write(
        d,
        "cal.toml",
        b"l1_mm = 50.0\nl2_mm = 50.0\n[enc1]\ncounts_per_rev = 8388608\nzero_count = 0\ndirection = \"Positive\"\n[enc2]\ncounts_per_rev = 8388608\nzero_count = 0\ndirection = \"Positive\"\n",
    );
    let rec = write(
        d,
        "rec.csv",
        b"seq,t_us,enc1,enc2,d_mm\n0,0,1,2,100\n1,10,3,x,100\n",
    );
    fails(
        &[
            "recompute",
            "--record",
            &rec,
            "--calibration",
            &good,
            "-o",
            &rec,
        ],
        2,
        "would be written over the record",
    );
    let out = d.join("out.csv");
    let out = out.to_str().unwrap();
    fails(
        &[
            "recompute",
            "--record",
            &rec,
            "--calibration",
            &good,
            "-o",
            out,
        ],
        2,
        "rec.csv:3:8: enc2: `x` is not an integer",
    );
    assert!(!Path::new(out).exists());
    fails(
        &[
            "recompute",
            "--record",
            &rec,
            "--calibration",
            &nominal,
            "-o",
            out,
        ],
        2,
        "nominal.toml:2:9:",
    );
}
