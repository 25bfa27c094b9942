//! `jdbb simulate` → `jdbb diagnose` through the binary: the documented JSON, the report files,
//! the seed 002 real data, and bad input (clear error with file:line:column, exit code 2).
use std::path::Path;
mod common;
use common::jdbb;

fn simulate(dir: &Path, name: &str, extra: &[&str]) -> String {
    let out = dir.join(name);
    let out_s = out.to_str().unwrap().to_string();
    let mut args = vec![
        "simulate",
        "--radius",
        "60",
        "--rate",
        "200",
        "--sigma-um",
        "0.3",
        "--resolution-um",
        "0.1",
        "--seed",
        "4",
        "-o",
        &out_s,
        "--effect",
        "setup_offset=25,-15,0",
    ];
    args.extend_from_slice(extra);
    let o = jdbb(&args);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    out_s
}

#[test]
fn simulate_then_diagnose_json_names_the_hidden_effects() {
    let dir = tempfile::tempdir().unwrap();
    let file = simulate(
        dir.path(),
        "s.csv",
        &[
            "--pitch",
            "x=10,y=10",
            "--effect",
            "cyclic_x=2.5@30",
            "--effect",
            "servo_mismatch_xy=0.4",
        ],
    );
    let report = dir.path().join("rep");
    let o = jdbb(&[
        "diagnose",
        "--samples",
        &file,
        "--pitch",
        "x=10,y=10",
        "--json",
        "--report",
        report.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert!(v["samples"].as_u64().unwrap() > 1000);
    assert!(v["baseline"]["rms_um"].as_f64().unwrap() > 5.0);
    let effects = v["effects"].as_array().unwrap();
    let names: Vec<&str> = effects
        .iter()
        .map(|e| e["name"].as_str().unwrap())
        .collect();
    assert_eq!(&names[..2], &["setup_offset", "length_offset"]);
    let mut machine: Vec<&str> = names[2..].to_vec();
    machine.sort();
    assert_eq!(machine, vec!["cyclic_x", "servo_mismatch_xy"]);
    let cyc = effects.iter().find(|e| e["name"] == "cyclic_x").unwrap();
    assert_eq!(cyc["unit"], "um");
    let (val, sig) = (
        cyc["value"].as_f64().unwrap(),
        cyc["sigma"].as_f64().unwrap(),
    );
    common::tolerance::assert_unbiased("cyclic_x", val, sig, 2.5, 0.0, &v.to_string());
    assert!(cyc["params"]["sin_um"].is_number() && cyc["rms_after_um"].is_number());
    let final_rms = v["final"]["rms_um"].as_f64().unwrap();
    assert!(final_rms < 0.4, "{final_rms}");
    assert!(
        (v["gain"].as_f64().unwrap() - v["baseline"]["rms_um"].as_f64().unwrap() / final_rms).abs()
            < 1e-9
    );
    assert!(v["confounded"].as_array().unwrap().iter().any(|g| g
        .as_array()
        .unwrap()
        .contains(&serde_json::json!("scale_x"))));
    for f in ["polar.svg", "polar.png", "diagnosis.json"] {
        let meta = std::fs::metadata(report.join(f)).unwrap();
        assert!(meta.len() > 1000, "{f} too small");
    }
    let svg = std::fs::read_to_string(report.join("polar.svg")).unwrap();
    assert!(svg.contains("G = ") && svg.contains("measured") && svg.contains("extended model"));
}

#[test]
fn human_summary_names_cause_and_confounding() {
    let dir = tempfile::tempdir().unwrap();
    let file = simulate(dir.path(), "s.csv", &["--effect", "scale_x=30"]);
    let o = jdbb(&["diagnose", "--samples", &file, "--verbose"]);
    assert!(o.status.success());
    let s = String::from_utf8_lossy(&o.stdout);
    assert!(s.contains("scale_mismatch_xy = "), "{s}");
    assert!(
        s.contains("confounded (this test cannot tell apart): length_offset, scale_x, scale_y"),
        "{s}"
    );
    assert!(s.contains("ideal machine (D = |p|): RMS"), "{s}");
}

#[test]
fn a_record_file_with_its_nominal_path_gives_the_same_diagnosis() {
    let dir = tempfile::tempdir().unwrap();
    let file = simulate(dir.path(), "s.csv", &["--effect", "backlash_x=5"]);
    let text = std::fs::read_to_string(&file).unwrap();
    // The recording starts 2 s before the motion (bar at rest, D = first value); the path file
    // holds the commanded positions on its own clock.
    let mut rec = String::from("seq,t_us,enc1,enc2,d_mm\n");
    let mut nominal = String::from("t_s,x_mm,y_mm,z_mm\n");
    let rows: Vec<Vec<&str>> = text
        .lines()
        .skip(1)
        .map(|l| l.split(',').collect())
        .collect();
    for i in 0..400 {
        rec.push_str(&format!("{i},{},0,0,{}\n", i * 5000, rows[0][4]));
    }
    for (i, r) in rows.iter().enumerate() {
        let t: f64 = r[0].parse().unwrap();
        let t_us = (t * 1e6).round() as i64 + 2_000_000;
        rec.push_str(&format!("{},{t_us},0,0,{}\n", i + 400, r[4]));
        nominal.push_str(&format!("{},{},{},{}\n", r[0], r[1], r[2], r[3]));
    }
    let (rf, pf) = (dir.path().join("rec.csv"), dir.path().join("path.csv"));
    std::fs::write(&rf, rec).unwrap();
    std::fs::write(&pf, nominal).unwrap();
    let a = jdbb(&["diagnose", "--samples", &file, "--json"]);
    let b = jdbb(&[
        "diagnose",
        "--record",
        rf.to_str().unwrap(),
        "--path",
        pf.to_str().unwrap(),
        "--path-offset-s",
        "2",
        "--json",
    ]);
    assert!(b.status.success(), "{}", String::from_utf8_lossy(&b.stderr));
    let (a, b): (serde_json::Value, serde_json::Value) = (
        serde_json::from_slice(&a.stdout).unwrap(),
        serde_json::from_slice(&b.stdout).unwrap(),
    );
    assert_eq!(a["samples"], b["samples"]);
    let names = |v: &serde_json::Value| -> Vec<String> {
        v["effects"]
            .as_array()
            .unwrap()
            .iter()
            .map(|e| e["name"].as_str().unwrap().to_string())
            .collect()
    };
    assert_eq!(names(&a), names(&b));
    assert!(names(&b).contains(&"backlash_x".to_string()));
    let fa = a["final"]["rms_um"].as_f64().unwrap();
    let fb = b["final"]["rms_um"].as_f64().unwrap();
    assert!((fa - fb).abs() < 1e-3 * fa, "{fa} {fb}");
    // Without the offset the times do not line up and the diagnosis sees a worse fit.
    let c = jdbb(&[
        "diagnose",
        "--record",
        rf.to_str().unwrap(),
        "--path",
        pf.to_str().unwrap(),
        "--json",
    ]);
    assert!(c.status.success());
    let c: serde_json::Value = serde_json::from_slice(&c.stdout).unwrap();
    assert!(c["final"]["rms_um"].as_f64().unwrap() > 3.0 * fb);
}

fn expect_input_error(text: &str, args: &[&str], want: &str) {
    let dir = tempfile::tempdir().unwrap();
    let f = dir.path().join("bad.csv");
    std::fs::write(&f, text).unwrap();
    let mut all = vec!["diagnose", "--samples", f.to_str().unwrap()];
    all.extend_from_slice(args);
    let o = jdbb(&all);
    assert_eq!(
        o.status.code(),
        Some(2),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let err = String::from_utf8_lossy(&o.stderr);
    let want = format!("{}:{want}", f.display());
    assert!(err.contains(&want), "wanted `{want}` in `{err}`");
    assert!(!err.contains("panicked"));
}

fn circle_rows(n: usize) -> String {
    (0..n)
        .map(|i| {
            let a = i as f64 * 0.1;
            format!(
                "{},{},{},0,50\n",
                i as f64 * 0.01,
                50.0 * a.cos(),
                50.0 * a.sin()
            )
        })
        .collect()
}

#[test]
fn bad_input_names_file_line_and_column() {
    let header = "t_s,x_mm,y_mm,z_mm,d_mm\n";
    expect_input_error(
        "t_s,x_mm,y_mm,z,d_mm\n0,1,2,3,4\n",
        &[],
        "1: missing column `z_mm`",
    );
    let mut nan = format!("{header}{}", circle_rows(40));
    nan.push_str("0.5,1,NaN,0,50\n");
    expect_input_error(&nan, &[], "42:7: y_mm is NaN");
    let back = format!("{header}{}0.1,1,1,0,50\n", circle_rows(40));
    expect_input_error(&back, &[], "42:1: time goes backwards");
    expect_input_error(
        &format!("{header}{}", circle_rows(5)),
        &[],
        "6: only 5 samples",
    );
    expect_input_error(
        &format!("{header}{}", circle_rows(40)),
        &["--pitch", "z=5"],
        "1:15: a pitch was given for axis z",
    );
    expect_input_error(
        &format!("{header}-1,50,0,0,abc\n{}", circle_rows(40)),
        &[],
        "2:11: d_mm: `abc` is not a number",
    );
}

#[test]
fn unknown_effect_and_missing_file_fail_cleanly() {
    let o = jdbb(&["simulate", "--effect", "wobble_x=3"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("unknown effect `wobble_x`"));
    // A missing input file is bad input (exit 2), and its cause is printed once.
    let o = jdbb(&["diagnose", "--samples", "/nonexistent/x.csv"]);
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("/nonexistent/x.csv"), "{err}");
    assert_eq!(err.matches("No such file or directory").count(), 1, "{err}");
}

#[test]
fn seed_002_turntable_runs_are_explained_by_eccentricity() {
    // Seed 002 (002_bd0d7a4ef10ebe3d.txt) Table 1, as in ../shared/data/dbb_c_turntable_table1.csv:
    // seven DBB runs while the C turntable turns, bar-length change in mm.
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("dbb_c_turntable_table1.csv");
    std::fs::write(&file, SEED_002_TABLE_1).unwrap();
    let data = file.to_str().unwrap();
    let o = jdbb(&["diagnose-rotary", "--samples", data, "--json"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let runs = v.as_array().unwrap();
    assert_eq!(runs.len(), 7);
    for r in runs {
        let name = r["run"].as_str().unwrap();
        let effects = r["effects"].as_array().unwrap();
        if name.contains("axial") {
            // Axial: a constant ~14 µm (the paper's Table 3 axial displacement averages 14.08 µm).
            assert_eq!(effects[0]["name"], "length_offset");
            assert!((effects[0]["value"].as_f64().unwrap() - 14.1).abs() < 0.5);
        } else {
            // Radial and tangential: the once-per-rev eccentricity of ~146 µm dominates.
            let e = effects
                .iter()
                .find(|e| e["name"] == "once_per_rev")
                .unwrap();
            assert!((e["value"].as_f64().unwrap() - 146.0).abs() < 2.0, "{name}");
        }
        assert!(r["gain"].as_f64().unwrap() > 50.0, "{name}");
        assert!(r["final"]["rms_um"].as_f64().unwrap() < 1.0, "{name}");
    }
}

/// Seed 002, Table 1 (measured changes of DBB bar length, Renishaw QC20-W, 0.1 µm resolution),
/// copied from the paper like ../shared/data/dbb_c_turntable_table1.csv.
const SEED_002_TABLE_1: &str = "\
angle_deg,dl1_radial_mm,dl1_tangential_mm,dl1_axial_mm,dl2_radial_mm,dl2_tangential_mm,dl3_radial_mm,dl3_tangential_mm\n\
0,-0.0002,0.0082,0.0143,-0.0148,0.0040,0.0017,0.0061\n\
20,0.0522,0.0032,0.0140,0.0379,0.0018,0.0530,0.0023\n\
40,0.1005,0.0174,0.0140,0.0856,0.0179,0.1025,0.0163\n\
60,0.1433,0.0485,0.0140,0.1271,0.0512,0.1427,0.0487\n\
80,0.1698,0.0915,0.0142,0.1519,0.0953,0.1704,0.0922\n\
100,0.1799,0.1411,0.0142,0.1599,0.1457,0.1804,0.1421\n\
120,0.1741,0.1913,0.0143,0.1526,0.1957,0.1725,0.1921\n\
140,0.1510,0.2378,0.0143,0.1275,0.2408,0.1492,0.2373\n\
160,0.1134,0.2715,0.0144,0.0879,0.2732,0.1112,0.2708\n\
180,0.0663,0.2910,0.0142,0.0403,0.2903,0.0647,0.2896\n\
200,0.0180,0.2934,0.0142,-0.0086,0.2910,0.0154,0.2907\n\
220,-0.0283,0.2783,0.0141,-0.0541,0.2732,-0.0310,0.2747\n\
240,-0.0686,0.2482,0.0142,-0.0933,0.2417,-0.0702,0.2439\n\
260,-0.0967,0.2069,0.0141,-0.1196,0.1992,-0.0982,0.2020\n\
280,-0.1105,0.1604,0.0139,-0.1309,0.1515,-0.1110,0.1533\n\
300,-0.1071,0.1105,0.0137,-0.1256,0.1026,-0.1073,0.1060\n\
320,-0.0864,0.0654,0.0139,-0.1029,0.0578,-0.0844,0.0618\n\
340,-0.0484,0.0295,0.0139,-0.0633,0.0236,-0.0468,0.0267\n\
360,-0.0002,0.0080,0.0136,-0.0145,0.0037,0.0020,0.0061\n\
";

/// The polylines of an SVG as (stroke colour, points).
fn svg_polylines(svg: &str) -> Vec<(String, Vec<(f64, f64)>)> {
    let attr = |el: &str, name: &str| -> String {
        let key = format!("{name}=\"");
        el.find(&key)
            .map(|i| {
                let rest = &el[i + key.len()..];
                rest[..rest.find('"').unwrap()].to_string()
            })
            .unwrap_or_default()
    };
    svg.split("<polyline")
        .skip(1)
        .map(|el| {
            let el = &el[..el.find('>').unwrap()];
            let pts = attr(el, "points")
                .split_whitespace()
                .map(|p| {
                    let (x, y) = p.split_once(',').unwrap();
                    (x.parse().unwrap(), y.parse().unwrap())
                })
                .collect();
            (attr(el, "stroke"), pts)
        })
        .collect()
}

#[test]
fn polar_plot_has_no_chord_and_states_the_removed_setup() {
    // A ccw circle, then the cw circle starts at 180°: drawn as one polyline this would be a
    // chord through the centre. Set-up: the table ball at (−20, +10) µm from where assumed (the
    // spindle ball is at p − c from it), bar 5 µm long; a 2 µm ellipse.
    let dir = tempfile::tempdir().unwrap();
    let mut csv = String::from("t_s,x_mm,y_mm,z_mm,d_mm\n");
    let r = 60.0f64;
    for k in 0..1440 {
        let deg = if k < 720 {
            0.5 * k as f64
        } else {
            180.0 - 0.5 * (k - 720) as f64
        };
        let a = deg.to_radians();
        let (x, y) = (r * a.cos(), r * a.sin());
        let d = (x + 0.020).hypot(y - 0.010) + 0.005 + 0.002 * (2.0 * a).cos();
        csv.push_str(&format!("{},{x:.7},{y:.7},0,{d:.7}\n", 0.01 * k as f64));
    }
    let file = dir.path().join("jump.csv");
    std::fs::write(&file, csv).unwrap();
    let report = dir.path().join("rep");
    let o = jdbb(&[
        "diagnose",
        "--samples",
        file.to_str().unwrap(),
        "--report",
        report.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let svg = std::fs::read_to_string(report.join("polar.svg")).unwrap();
    assert!(
        svg.contains("set-up removed"),
        "title must say the set-up is removed"
    );
    // D = |p + (20, −10) µm| puts the table ball at (−20, 10) µm; noise-free data support many
    // digits (the residual RMS is a fraction of a nanometre).
    let caption = svg
        .split("Set-up removed (fitted): table ball at ")
        .nth(1)
        .expect("caption must give the removed set-up");
    let number = |key: &str| -> f64 {
        let rest = caption.split(key).nth(1).unwrap();
        rest.split(' ').next().unwrap().parse().unwrap()
    };
    for (key, want) in [("x = ", -20.0), ("y = ", 10.0), ("length offset e = ", 5.0)] {
        let got = number(key);
        assert!((got - want).abs() < 0.01, "{key}{got}: {caption}");
    }
    assert!(caption.contains("from where assumed"), "{caption}");
    let lines = svg_polylines(&svg);
    // The ideal machine's zero circle gives the plot centre.
    let ring = lines
        .iter()
        .find(|(c, p)| c == "#00A000" && p.len() > 100)
        .expect("ideal-machine circle");
    let n = ring.1.len() as f64;
    let cx = ring.1.iter().map(|p| p.0).sum::<f64>() / n;
    let cy = ring.1.iter().map(|p| p.1).sum::<f64>() / n;
    let mut traces = 0;
    for (colour, pts) in lines.iter().filter(|(_, p)| p.len() > 400) {
        traces += 1;
        for w in pts.windows(2) {
            let a0 = (w[0].1 - cy).atan2(w[0].0 - cx);
            let a1 = (w[1].1 - cy).atan2(w[1].0 - cx);
            let da = (a1 - a0 + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU)
                - std::f64::consts::PI;
            assert!(
                da.abs() < 6f64.to_radians(),
                "{colour} polyline jumps {:.0}° from {:?} to {:?}",
                da.to_degrees(),
                w[0],
                w[1]
            );
        }
    }
    // Measured and model, ccw and cw.
    assert!(traces >= 4, "{traces} traces");
}

/// The whole number right before each occurrence of `marker` in `text`.
fn percents_before(text: &str, marker: &str) -> Vec<u32> {
    let pieces: Vec<&str> = text.split(marker).collect();
    pieces[..pieces.len() - 1]
        .iter()
        .filter_map(|piece| {
            let digits: String = piece
                .chars()
                .rev()
                .take_while(|c| c.is_ascii_digit())
                .collect::<Vec<_>>()
                .into_iter()
                .rev()
                .collect();
            digits.parse().ok()
        })
        .collect()
}

/// The whole numbers before " %" in `text` after each occurrence of `marker`.
fn percents_after(text: &str, marker: &str) -> Vec<u32> {
    text.split(marker)
        .skip(1)
        .filter_map(|rest| {
            let n: String = rest
                .trim_start()
                .chars()
                .take_while(|c| c.is_ascii_digit())
                .collect();
            n.parse().ok()
        })
        .collect()
}

#[test]
fn every_output_shows_one_g_per_circle_and_direction_shares_of_100_and_plain_words() {
    // Two radii, three effects: backlash, squareness and a servo mismatch.
    let dir = tempfile::tempdir().unwrap();
    let file = simulate(
        dir.path(),
        "s.csv",
        &[
            "--radius",
            "90",
            "--effect",
            "backlash_x=5",
            "--effect",
            "squareness_xy=20",
            "--effect",
            "servo_mismatch_xy=0.3",
        ],
    );
    let rep = dir.path().join("rep");
    let o = jdbb(&[
        "diagnose",
        "--samples",
        &file,
        "--report",
        rep.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let text = String::from_utf8_lossy(&o.stdout).to_string();
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(rep.join("diagnosis.json")).unwrap())
            .unwrap();
    let html = std::fs::read_to_string(rep.join("report.html")).unwrap();
    let svg = std::fs::read_to_string(rep.join("polar.svg")).unwrap();

    // G: the JSON's minimum-zone G of each circle and direction, shown with the digits of the
    // noise (two significant digits of the residual RMS), is the figure of the text, the
    // report's table and plot titles and the overview plot's caption.
    let noise = v["final"]["rms_um"].as_f64().unwrap();
    let decimals = (1 - noise.log10().floor() as i32).max(0) as usize;
    let circles = v["circles"].as_array().unwrap();
    assert_eq!(circles.len(), 2);
    let mut largest = 0.0f64;
    for (k, c) in circles.iter().enumerate() {
        let g = |dir: &str| c[dir]["g_um"].as_f64().unwrap();
        let (ccw, cw) = (g("ccw"), g("cw"));
        largest = largest.max(ccw).max(cw);
        assert_eq!(c["g_um"].as_f64().unwrap(), ccw.max(cw));
        let (ccw, cw) = (format!("{ccw:.decimals$}"), format!("{cw:.decimals$}"));
        let line = format!("G ccw {ccw} µm, cw {cw} µm");
        assert!(
            text.contains(&format!("circle {} (r ", k + 1)) && text.contains(&line),
            "text lacks `{line}`:\n{text}"
        );
        assert!(
            svg.contains(&format!("G ccw {ccw} µm, cw {cw} µm")),
            "polar.svg lacks {line}"
        );
        assert!(
            html.contains(&format!("G ccw {ccw} µm, cw {cw} µm, H")),
            "report plot title lacks {line}"
        );
        assert!(
            html.contains(&format!(
                "<td class=\"num\">{ccw}</td><td class=\"num\">{cw}</td>"
            )),
            "report table lacks {line}"
        );
    }
    assert_eq!(v["circular_deviation_g_um"].as_f64().unwrap(), largest);
    assert_eq!(v["minimum_zone"]["g_um"].as_f64().unwrap(), largest);
    assert!(html.contains(&format!(
        "largest circular deviation G = {largest:.decimals$} µm"
    )));
    assert!(svg.contains(&format!("G = {largest:.decimals$} µm (largest)")));

    // Shares: the JSON's add up to 1 with the residual's; the printed whole percentages add
    // up to 100 in the text and in the report, and are the same numbers.
    let effects = v["effects"].as_array().unwrap();
    let json_sum: f64 = effects
        .iter()
        .filter_map(|e| e["share"].as_f64())
        .sum::<f64>()
        + v["residual_share"].as_f64().unwrap();
    assert!((json_sum - 1.0).abs() < 1e-9, "{json_sum}");
    let in_text = percents_before(&text, " % of the mean square");
    assert_eq!(in_text.len(), effects.len() - 2 + 1, "{text}");
    assert_eq!(in_text.iter().sum::<u32>(), 100, "{text}");
    let mut in_html = percents_after(&html, "</span> ");
    in_html.extend(percents_after(&html, "<td class=\"share\">"));
    assert_eq!(in_html.len(), in_text.len(), "{html}");
    assert_eq!(in_html.iter().sum::<u32>(), 100);
    let (mut a, mut b) = (in_text.clone(), in_html.clone());
    a.sort();
    b.sort();
    assert_eq!(a, b);

    // The words of the trade: no paper references or symbols for people; the backlash's
    // words follow its sign (today's: positive = play).
    for (what, out) in [("text", &text), ("report", &html), ("plot", &svg)] {
        for bad in ["seed 000", "eq. ", "dtau", "ΔBIC", "BIC"] {
            assert!(!out.contains(bad), "{what} says `{bad}`");
        }
    }
    // Digits from σ: each machine effect's value and σ are printed to two significant digits
    // of σ, in the text and in the report.
    for e in &effects[2..] {
        let (value, sigma) = (e["value"].as_f64().unwrap(), e["sigma"].as_f64().unwrap());
        let d = (1 - sigma.log10().floor() as i32).max(0) as usize;
        let shown = format!("{value:.d$} ± {sigma:.d$}");
        let name = e["name"].as_str().unwrap();
        assert!(
            text.contains(&format!("{name} = {shown} ")),
            "{shown}:\n{text}"
        );
        assert!(
            html.contains(&format!("<td class=\"num\">{shown} ")),
            "{shown}"
        );
    }
    let b = effects.iter().find(|e| e["name"] == "backlash_x").unwrap();
    let words = if b["value"].as_f64().unwrap() > 0.0 {
        "X: lost motion (play) at reversal"
    } else {
        "X: axis runs ahead at reversal (over-compensation)"
    };
    assert!(b["cause"].as_str().unwrap().starts_with(words), "{b}");
    assert!(text.contains(words) && html.contains(words));
}
