//! `report.html` in a real browser: headless Chromium renders the page `jdbb diagnose --report`
//! writes to a PNG, which must show the page (not a blank or an error page). Chromium comes from
//! `scripts/setup.sh`; where it cannot be had the test says so and is skipped, unless
//! `JDBB_REQUIRE_CHROMIUM=1`. `JDBB_CHROMIUM` names another binary.
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};
mod common;
use common::ok;

/// The Chromium `jdbb diagnose --pdf` prints with (`JDBB_CHROMIUM`, else on `PATH`); None, said
/// as a skip, without one (a failure with `JDBB_REQUIRE_CHROMIUM=1`).
fn chromium_or_skip() -> Option<PathBuf> {
    let found = jdbb::report::pdf::find_chromium().ok();
    if found.is_none() {
        let msg = "chromium not found (scripts/setup.sh installs it; JDBB_CHROMIUM names a binary)";
        if std::env::var("JDBB_REQUIRE_CHROMIUM").as_deref() == Ok("1") {
            panic!("{msg}");
        }
        println!("skipped: {msg}");
    }
    found
}

/// A page written by `jdbb diagnose --report` for a failing machine, with `extra` options.
fn report_with(dir: &Path, extra: &[&str]) -> PathBuf {
    let csv = dir.join("t.csv");
    let rep = dir.join("rep");
    ok(&[
        "simulate",
        "--radius",
        "50",
        "--radius",
        "80",
        "--rate",
        "100",
        "--effect",
        "backlash_x=8",
        "--effect",
        "squareness_xy=30",
        "--sigma-um",
        "0.3",
        "-o",
        csv.to_str().unwrap(),
    ]);
    let mut args = vec![
        "diagnose",
        "--samples",
        csv.to_str().unwrap(),
        "--report",
        rep.to_str().unwrap(),
        "--machine",
        "mill <1> & co",
        "--tolerance-um",
        "5",
        "--date",
        "2026-11-23",
    ];
    args.extend_from_slice(extra);
    ok(&args);
    rep.join("report.html")
}

/// [`report_with`] and no ISO 230-4 conditions given.
fn report(dir: &Path) -> PathBuf {
    report_with(dir, &[])
}

/// The ISO 230-4 conditions of [`report_with`] in the tests below.
fn conditions(comp: &Path) -> Vec<String> {
    [
        "--operator",
        "A. Turner",
        "--machine-temperature-c",
        "20.5",
        "--instrument-temperature-c",
        "-1.25",
        "--table-ball",
        "x=250,y=150.5,z=-300",
        "--compensation-file",
        comp.to_str().unwrap(),
    ]
    .map(String::from)
    .to_vec()
}

#[test]
fn the_iso_230_4_items_are_stated_or_said_to_be_missing() {
    let dir = tempfile::tempdir().unwrap();
    let comp = dir.path().join("comp.ini");
    std::fs::write(&comp, "[JOINT_0]\nBACKLASH = 0.010 # <old>\n").unwrap();
    let c = conditions(&comp);
    let c: Vec<&str> = c.iter().map(String::as_str).collect();
    let html = std::fs::read_to_string(report_with(dir.path(), &c)).unwrap();
    for want in [
        "<th>Operator</th><td>A. Turner</td>",
        "<th>Machine temperature</th><td>20.5 °C</td>",
        "<th>Instrument temperature</th><td>-1.25 °C</td>",
        "<td>x = 250.000 mm, y = 150.500 mm, z = -300.000 mm</td>",
        "BACKLASH = 0.010 # &lt;old&gt;",
        "serial not reported",
        "F max / min ccw µm",
        "F (radial deviation, ISO 230-4)",
    ] {
        assert!(html.contains(want), "{want} missing");
    }
    let json: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(dir.path().join("rep/diagnosis.json")).unwrap(),
    )
    .unwrap();
    assert_eq!(json["operator"], "A. Turner");
    assert_eq!(json["temperature_c"]["instrument"], -1.25);
    assert_eq!(json["table_ball_mm"]["y"], 150.5);
    assert!(json["compensation"]["text"]
        .as_str()
        .unwrap()
        .contains("BACKLASH = 0.010"));
    // Nothing given: each item says so and how to give it.
    let dir = tempfile::tempdir().unwrap();
    let html = std::fs::read_to_string(report(dir.path())).unwrap();
    for want in [
        "not given (--operator)",
        "not given (--machine-temperature-c)",
        "not given (--instrument-temperature-c)",
        "not given (--table-ball",
        "not given (jdbb diagnose --compensation TEXT or --compensation-file FILE)",
        "<th>Plan</th><td>not given",
    ] {
        assert!(html.contains(want), "{want} missing");
    }
}

#[test]
fn the_calibration_the_date_and_the_feed_read_as_a_person_needs_them() {
    let dir = tempfile::tempdir().unwrap();
    let cal = dir.path().join("bar-2026.json");
    std::fs::write(
        &cal,
        r#"{"l1_mm": 50.0123, "l2_mm": 49.9871,
 "enc1": {"counts_per_rev": 8388608, "zero_count": 1234, "direction": "Positive", "zero_offset_rad": 0.00021},
 "enc2": {"counts_per_rev": 8388608, "zero_count": -77, "direction": "Negative"},
 "axes_skew_rad": 0.0002}"#,
    )
    .unwrap();
    let html = std::fs::read_to_string(report_with(
        dir.path(),
        &["--calibration", cal.to_str().unwrap()],
    ))
    .unwrap();
    // The file's name, the bars in mm, the angles in degrees; the raw keys only under <details>.
    let row = html
        .lines()
        .find(|l| l.starts_with("<tr><th>Instrument calibration</th>"))
        .unwrap();
    let (shown, details) = row.split_once("<details>").unwrap();
    assert!(
        shown.contains("bar-2026.json</b>: bars L1 50.0123 mm, L2 49.9871 mm; encoder 1: 8388608 counts/rev, zero at count 1234, direction positive, fine zero 0.0120°"),
        "{row}"
    );
    assert!(shown.contains("axes skew 0.0115°"), "{row}");
    assert!(!shown.contains("enc1.") && !shown.contains("_rad"), "{row}");
    assert!(
        details.starts_with("<summary>all 21 values of the file</summary>")
            && details.contains("<td>enc1.direction</td><td class=\"num\">Positive</td>")
            && details.contains("0.0002 (0.011459°)"),
        "{row}"
    );
    // --date given: the date is the test's; the feed from samples has no programmed feed.
    assert!(
        html.contains(
            "<tr><th>Date of the test (UTC, --date)</th><td>2026-11-23T00:00:00Z</td></tr>"
        ),
        "date"
    );
    assert!(
        html.contains(
            "measured feed 1000 mm/min (programmed feed and override: not known without a plan)"
        ),
        "feed"
    );
    let json: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(dir.path().join("rep/diagnosis.json")).unwrap(),
    )
    .unwrap();
    assert_eq!(json["date_of"], "test");
    assert!(json["calibration_file"]
        .as_str()
        .unwrap()
        .ends_with("bar-2026.json"));
}

#[test]
fn radial_deviation_f_is_from_the_nominal_radius_g_is_not() {
    // A bar 5 µm long everywhere: the plot and G remove the length offset, F must not.
    let dir = tempfile::tempdir().unwrap();
    let csv = dir.path().join("t.csv");
    ok(&[
        "simulate",
        "--radius",
        "50",
        "--rate",
        "100",
        "--effect",
        "length_offset=5",
        "--effect",
        "backlash_x=4",
        "--sigma-um",
        "0.2",
        "--seed",
        "7",
        "-o",
        csv.to_str().unwrap(),
    ]);
    let out = ok(&["diagnose", "--samples", csv.to_str().unwrap(), "--json"]);
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    let c = &v["circles"][0];
    for dir in ["ccw", "cw"] {
        let f = &c["radial_deviation_f"][dir];
        let (max, min) = (f["max_um"].as_f64().unwrap(), f["min_um"].as_f64().unwrap());
        let g = c[dir]["g_um"].as_f64().unwrap();
        // Backlash moves the path by up to ±2 µm about the 5 µm offset: F from about 3 to 7 µm.
        assert!(
            max > 5.5 && max < 8.0 && min > 2.0 && min < 4.5,
            "{dir}: F {max} / {min}"
        );
        // F spans at least the minimum zone (its centre is the least-squares one).
        assert!(
            max - min >= g - 1e-9 && g < 6.0,
            "{dir}: F {max} / {min}, G {g}"
        );
    }
}

#[test]
fn the_page_is_self_contained_and_says_what_it_must() {
    let dir = tempfile::tempdir().unwrap();
    let html = std::fs::read_to_string(report(dir.path())).unwrap();
    for fetch in [
        "<script", "<link", "src=", "href=", "url(", "@import", "<iframe",
    ] {
        assert!(!html.contains(fetch), "the page fetches something: {fetch}");
    }
    assert!(html.contains("FAIL: largest circular deviation G"));
    assert!(
        html.contains("mill &lt;1&gt; &amp; co"),
        "the name is escaped"
    );
    assert!(html.contains("2026-11-23T00:00:00Z"));
    assert!(html.contains("minimum-zone centre"));
    // The polar plot of all circles on page one, then one per circle; effects ranked by share.
    assert_eq!(html.matches("<svg").count(), 3);
    let bx = html.find("<td>backlash_x</td>").unwrap();
    let sq = html.find("<td>squareness_xy</td>").unwrap();
    assert!(bx < sq, "backlash_x has the larger share here");
}

#[test]
fn chromium_renders_the_report() {
    let Some(chromium) = chromium_or_skip() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let comp = dir.path().join("comp.ini");
    std::fs::write(&comp, "[JOINT_0]\nBACKLASH = 0.010\n").unwrap();
    let c = conditions(&comp);
    let html = report_with(
        dir.path(),
        &c.iter().map(String::as_str).collect::<Vec<_>>(),
    );
    let png = match std::env::var_os("JDBB_REPORT_PNG") {
        // Where to keep the rendered page, to look at it.
        Some(p) => PathBuf::from(p),
        None => dir.path().join("report.png"),
    };
    let profile = dir.path().join("profile");
    let mut child = Command::new(&chromium)
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
            "--window-size=1200,1600",
            &format!("--screenshot={}", png.display()),
            &format!("file://{}", html.display()),
        ])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let t0 = Instant::now();
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        if t0.elapsed() > Duration::from_secs(120) {
            let _ = child.kill();
            panic!("chromium did not finish in 120 s");
        }
        std::thread::sleep(Duration::from_millis(100));
    };
    assert!(
        status.success(),
        "{} exited with {status}",
        chromium.display()
    );
    let bytes = std::fs::read(&png).unwrap();
    assert!(bytes.len() > 20_000, "PNG of {} bytes", bytes.len());
    let img = image::load_from_memory(&bytes).unwrap().to_rgb8();
    assert_eq!(img.dimensions(), (1200, 1600));
    // Not blank: plenty of ink, many colours, and the FAIL banner's red (#fbdcdc) near the top.
    let ink = img
        .pixels()
        .filter(|p| p.0.iter().any(|&c| c < 200))
        .count();
    assert!(ink > 20_000, "{ink} dark pixels");
    let mut colours: Vec<[u8; 3]> = img.pixels().map(|p| p.0).collect();
    colours.sort();
    colours.dedup();
    assert!(colours.len() > 50, "{} colours", colours.len());
    let banner = (0..300)
        .flat_map(|y| (0..1200).map(move |x| (x, y)))
        .filter(|&(x, y)| {
            let p = img.get_pixel(x, y).0;
            (p[0] as i32 - 251).abs() <= 3
                && (p[1] as i32 - 220).abs() <= 3
                && (p[2] as i32 - 220).abs() <= 3
        })
        .count();
    assert!(banner > 5_000, "the FAIL banner: {banner} pixels");
    println!(
        "chromium rendered report.html: {} bytes of PNG, {ink} dark pixels, {} colours",
        bytes.len(),
        colours.len()
    );
}

#[test]
fn the_serial_the_device_reported_is_in_the_report() {
    // A record as `jdbb record` writes it: the serial line right after the header.
    let dir = tempfile::tempdir().unwrap();
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let text = std::fs::read_to_string(root.join("data/examples/ballbar-backlash.csv")).unwrap();
    let header_end = text.find("seq,t_us,enc1,enc2,d_mm\n").unwrap() + 24;
    let (header, rows) = text.split_at(header_end);
    let rec = dir.path().join("rec.csv");
    std::fs::write(
        &rec,
        format!("{header}# instrument_serial: 3F0029000851383235363438\n{rows}"),
    )
    .unwrap();
    let plan = dir.path().join("plan");
    ok(&[
        "plan",
        "--radius",
        "90",
        "--feed",
        "2000",
        "--centre",
        "100,50,-20",
        "--out",
        plan.to_str().unwrap(),
    ]);
    let rep = dir.path().join("rep");
    ok(&[
        "diagnose",
        "--record",
        rec.to_str().unwrap(),
        "--plan",
        plan.join("plan.json").to_str().unwrap(),
        "--report",
        rep.to_str().unwrap(),
    ]);
    let html = std::fs::read_to_string(rep.join("report.html")).unwrap();
    assert!(html.contains("<td>J-DBB, serial 3F0029000851383235363438</td>"));
    // No --date: the date is the diagnosis', and says so.
    assert!(
        html.contains("<tr><th>Date of the diagnosis (UTC)</th><td>")
            && html.contains(
                " (when jdbb diagnose ran; the test&#39;s date was not given: --date)</td>"
            ),
        "date"
    );
    // The feed the record shows, the programmed feed and the override beside it (the record
    // ran at 98 % override).
    assert!(
        html.contains(
            "measured feed 1961 mm/min (programmed 2000 mm/min, override 98.05 % as measured)"
        ),
        "feed"
    );
    // Where the data arcs are: after the 180° lead-in from the feed-in at 0°.
    assert!(
        html.contains("full circles: feed-in at 0°, lead-in 180°, data 180°→540° ccw (one turn) then 540°→180° cw, overshoot 180° each way"),
        "arc"
    );
    // The plan as a table, not JSON.
    assert!(html.contains("<th>bar length D mm</th>") && !html.contains("\"segments\""));
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(rep.join("diagnosis.json")).unwrap())
            .unwrap();
    assert_eq!(json["instrument"]["serial"], "3F0029000851383235363438");
}

#[test]
fn what_was_not_named_is_on_the_page_with_its_reason() {
    // The README's first test: a reversal spike is tried at X's reversals and not named.
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path().to_str().unwrap();
    let p = |f: &str| format!("{d}/{f}");
    ok(&[
        "plan",
        "--radius",
        "90",
        "--feed",
        "1000",
        "--centre",
        "100,50,-20",
        "--out",
        &p("plan"),
    ]);
    std::fs::write(p("m.toml"), ok(&["simulate", "--machine"])).unwrap();
    ok(&[
        "simulate",
        "--plan",
        &p("plan/plan.json"),
        "--machine",
        &p("m.toml"),
        "-o",
        &p("rec.csv"),
    ]);
    ok(&[
        "diagnose",
        "--record",
        &p("rec.csv"),
        "--plan",
        &p("plan/plan.json"),
        "--report",
        &p("rep"),
    ]);
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(p("rep/diagnosis.json")).unwrap()).unwrap();
    let page = std::fs::read_to_string(p("rep/report.html")).unwrap();
    let tried = json["not_significant"].as_array().unwrap();
    assert!(
        !tried.is_empty(),
        "this test names a spike it tried: {json}"
    );
    for w in tried {
        let name = w["name"].as_str().unwrap();
        let reason = w["reason"].as_str().unwrap();
        assert!(
            page.contains(&format!("Not named: {name} = ")) && page.contains(reason),
            "{name} is not on the page"
        );
    }
    for b in json["below_floor"].as_array().unwrap() {
        let name = b["name"].as_str().unwrap();
        assert!(page.contains(&format!("below the reporting floor: {name} ")));
    }
}

/// `jdbb diagnose --samples` of a one-circle test at `rate_hz` into `dir/rep` with `extra`
/// options; the report directory.
fn one_circle_report(dir: &Path, plane: &str, rate_hz: &str, extra: &[&str]) -> PathBuf {
    let csv = dir.join("c.csv");
    ok(&[
        "simulate",
        "--radius",
        "50",
        "--plane",
        plane,
        "--rate",
        rate_hz,
        "--effect",
        "backlash_x=8",
        "--sigma-um",
        "0.3",
        "-o",
        csv.to_str().unwrap(),
    ]);
    let rep = dir.join("rep");
    let mut args = vec![
        "diagnose",
        "--samples",
        csv.to_str().unwrap(),
        "--report",
        rep.to_str().unwrap(),
        "--machine",
        "mill 7",
        "--tolerance-um",
        "5",
    ];
    args.extend_from_slice(extra);
    ok(&args);
    rep
}

#[test]
fn a_long_record_makes_a_small_report_with_its_extremes() {
    // 150 000 samples: the page was 2.4 MB (every sample a point of its plot); traces are drawn
    // through each bin's least and largest deviation, so it stays small whatever the length.
    let dir = tempfile::tempdir().unwrap();
    let rep = one_circle_report(dir.path(), "xy", "4000", &[]);
    let bytes = std::fs::metadata(rep.join("report.html")).unwrap().len();
    assert!(bytes <= 2_000_000, "report.html is {bytes} bytes");
    let svg = std::fs::metadata(rep.join("polar.svg")).unwrap().len();
    assert!(svg <= 1_000_000, "polar.svg is {svg} bytes");
}

/// The (x, y) of the SVG `<text>` whose content is `label`.
fn text_at(svg: &str, label: &str) -> (f64, f64) {
    let end = svg
        .find(&format!(">\n{label}\n</text>"))
        .unwrap_or_else(|| panic!("no text {label}"));
    let start = svg[..end].rfind("<text").unwrap();
    let tag = &svg[start..end];
    let attr = |name: &str| -> f64 {
        let k = tag.find(&format!(" {name}=\"")).unwrap() + name.len() + 3;
        tag[k..k + tag[k..].find('"').unwrap()].parse().unwrap()
    };
    (attr("x"), attr("y"))
}

#[test]
fn a_zx_plot_is_seen_from_the_front_with_z_up_and_names_its_axes() {
    let dir = tempfile::tempdir().unwrap();
    let rep = one_circle_report(dir.path(), "zx", "100", &[]);
    let svg = std::fs::read_to_string(rep.join("polar.svg")).unwrap();
    // The angle runs from +Z towards +X: +Z (0°) is drawn up, +X (90°) to the right.
    let (zx, zy) = text_at(&svg, "0° +Z");
    let (xx, xy) = text_at(&svg, "90° +X");
    let (mx, _) = text_at(&svg, "270° −X");
    let (_, my) = text_at(&svg, "180° −Z");
    assert!(
        zy < my && (zx - 400.0).abs() < 5.0,
        "+Z at ({zx}, {zy}), −Z at y {my}"
    );
    assert!(
        xx > mx && (xy - zy).abs() > 100.0,
        "+X at ({xx}, {xy}), −X at x {mx}"
    );
    assert!(svg.contains("seen from the front of the machine (from −Y), +X right, +Z up"));
}

#[test]
fn without_chromium_pdf_says_what_to_install_and_writes_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let csv = dir.path().join("c.csv");
    ok(&[
        "simulate",
        "--radius",
        "50",
        "--rate",
        "50",
        "-o",
        csv.to_str().unwrap(),
    ]);
    let rep = dir.path().join("rep");
    let out = common::command()
        .env("PATH", dir.path())
        .env_remove("JDBB_CHROMIUM")
        .args([
            "diagnose",
            "--samples",
            csv.to_str().unwrap(),
            "--report",
            rep.to_str().unwrap(),
            "--pdf",
        ])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(1));
    let err = common::stderr(&out);
    assert!(
        err.contains("--pdf needs Chromium") && err.contains("apt install chromium"),
        "{err}"
    );
    assert!(!rep.exists(), "nothing written");
}

#[test]
fn the_pdf_s_page_one_has_the_verdict_the_polar_plot_and_the_ranked_effects() {
    if chromium_or_skip().is_none() {
        return;
    }
    if Command::new("pdftotext").arg("-v").output().is_err() {
        let msg = "pdftotext not found (scripts/setup.sh installs poppler-utils)";
        if std::env::var("JDBB_REQUIRE_CHROMIUM").as_deref() == Ok("1") {
            panic!("{msg}");
        }
        println!("skipped: {msg}");
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    // JDBB_CHROMIUM, if set, is inherited: jdbb prints with the Chromium found here.
    let rep = report_with(dir.path(), &["--pdf"])
        .parent()
        .unwrap()
        .to_path_buf();
    let pdf = rep.join("report.pdf");
    // Page one as poppler reads it: machine, test, verdict, the polar plot's own text, the
    // effects in the order of their share.
    let text = Command::new("pdftotext")
        .args(["-f", "1", "-l", "1", "-layout"])
        .arg(&pdf)
        .arg("-")
        .output()
        .unwrap();
    let page = String::from_utf8_lossy(&text.stdout).into_owned();
    for want in [
        "Circular test report: mill <1> & co",
        "Test: plane XY, 2 circles",
        "FAIL: largest circular deviation G",
        "J-DBB circular test, set-up removed",
        "0° +X",
        "90° +Y",
        "What the errors are, largest share first",
    ] {
        assert!(page.contains(want), "page one lacks {want:?}:\n{page}");
    }
    let (bx, sq) = (page.find("backlash_x"), page.find("squareness_xy"));
    assert!(
        matches!((bx, sq), (Some(b), Some(s)) if b < s),
        "ranked effects on page one:\n{page}"
    );
    // And the plot is drawn, not only its words: page one rendered has the traces' colours.
    let png = dir.path().join("p1");
    let done = Command::new("pdftoppm")
        .args(["-f", "1", "-l", "1", "-r", "100", "-png", "-singlefile"])
        .arg(&pdf)
        .arg(&png)
        .status()
        .unwrap();
    assert!(done.success());
    let img = image::open(dir.path().join("p1.png")).unwrap().to_rgb8();
    let near = |p: &image::Rgb<u8>, c: [i32; 3]| {
        p.0.iter().zip(c).all(|(&a, b)| (a as i32 - b).abs() <= 40)
    };
    let green = img.pixels().filter(|p| near(p, [0, 160, 0])).count();
    let blue = img.pixels().filter(|p| near(p, [31, 119, 180])).count();
    assert!(
        green > 100 && blue > 100,
        "green {green}, blue {blue} pixels"
    );
}
