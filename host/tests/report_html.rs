//! `report.html` in a real browser: headless Chromium renders the page `jdbb diagnose --report`
//! writes to a PNG, which must show the page (not a blank or an error page). Chromium comes from
//! `scripts/setup.sh`; where it cannot be had the test says so and is skipped, unless
//! `JDBB_REQUIRE_CHROMIUM=1`. `JDBB_CHROMIUM` names another binary.
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

fn jdbb(args: &[&str]) {
    let o = Command::new(env!("CARGO_BIN_EXE_jdbb"))
        .args(args)
        .output()
        .unwrap();
    assert!(
        o.status.success(),
        "jdbb {args:?}: {}",
        String::from_utf8_lossy(&o.stderr)
    );
}

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

/// A page written by `jdbb diagnose --report` for a failing machine.
fn report(dir: &Path) -> PathBuf {
    let csv = dir.join("t.csv");
    let rep = dir.join("rep");
    jdbb(&[
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
    jdbb(&[
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
    ]);
    rep.join("report.html")
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
    // One inline polar plot per circle, effects ranked by share.
    assert_eq!(html.matches("<svg").count(), 2);
    let bx = html.find("<td>backlash_x</td>").unwrap();
    let sq = html.find("<td>squareness_xy</td>").unwrap();
    assert!(bx < sq, "backlash_x has the larger share here");
}

#[test]
fn chromium_renders_the_report() {
    let Some(chromium) = find_chromium() else {
        let msg = "chromium not found (scripts/setup.sh installs it; JDBB_CHROMIUM names a binary)";
        if std::env::var("JDBB_REQUIRE_CHROMIUM").as_deref() == Ok("1") {
            panic!("{msg}");
        }
        println!("skipped: {msg}");
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let html = report(dir.path());
    let png = dir.path().join("report.png");
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
