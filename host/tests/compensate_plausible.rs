//! Issue 28, finding 9, as tests that failed before the fix: `jdbb compensate` emitted settings no
//! machine can have from an absurd scale in the diagnosis (LinuxCNC trims of 90 000 mm,
//! `M92 X42.105263`, a Klipper `rotation_distance` of 0.00004 mm) and built on an absurd value in
//! force (`$100=0.000001`). Each is refused (exit 2), naming the value and the limit, and nothing
//! is printed to enter or written.
use std::fs;
use std::path::Path;

mod common;
use common::{jdbb_in, stderr, stdout};

/// A diagnosis `name` in `dir` with one significant scale error of X (µm/m).
fn diagnosis(dir: &Path, name: &str, scale_x: f64) {
    let text = serde_json::json!({
        "format": 2,
        "samples": 1000,
        "effects": [
            {"name": "scale_x", "value": scale_x, "unit": "um/m", "sigma": 0.1,
             "params": {"a_um_per_m": scale_x}}
        ],
        "circles": [{"radius_mm": 50.0, "height_mm": 0.0, "feed_mm_min": 1000.0}],
    });
    fs::write(dir.join(name), serde_json::to_string(&text).unwrap()).unwrap();
}

/// `compensate` in `dir` with `args` exits 2 naming `want`, prints nothing to enter and writes
/// no file.
fn refused(dir: &Path, args: &[&str], want: &str) {
    let mut all = vec!["compensate"];
    all.extend(args);
    all.extend(["--out", "out"]);
    let o = jdbb_in(dir, &all);
    let e = stderr(&o);
    assert_eq!(o.status.code(), Some(2), "{args:?}: {e} {}", stdout(&o));
    assert!(e.contains(want), "{args:?}: wanted `{want}` in `{e}`");
    assert!(!e.contains("panicked"), "{e}");
    assert!(stdout(&o).is_empty(), "{args:?}: {}", stdout(&o));
    assert!(!dir.join("out").exists(), "{args:?}: files written");
}

#[test]
fn an_absurd_scale_is_refused_by_every_controller() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    fs::write(d.join("marlin.txt"), "M92 X80 Y80 Z400\n").unwrap();
    fs::write(
        d.join("klipper.cfg"),
        "[stepper_x]\nrotation_distance: 40\n",
    )
    .unwrap();
    fs::write(d.join("grbl.txt"), "$100=80\n").unwrap();
    for (scale, file) in [
        (1e9, "a.json"),
        (900_000.0, "b.json"),
        (-999_999.0, "c.json"),
    ] {
        diagnosis(d, file, scale);
        for (controller, current) in [
            ("linuxcnc", None),
            ("marlin", Some("marlin.txt")),
            ("klipper", Some("klipper.cfg")),
            ("grblhal", Some("grbl.txt")),
            ("grblhal", None),
        ] {
            let mut args = vec!["--diagnosis", file, "--controller", controller];
            if let Some(c) = current {
                args.extend(["--current", c]);
            }
            refused(d, &args, "beyond 10000 µm/m");
        }
    }
    // A plausible scale is still compensated.
    diagnosis(d, "ok.json", 30.0);
    let o = jdbb_in(
        d,
        &[
            "compensate",
            "--diagnosis",
            "ok.json",
            "--controller",
            "marlin",
            "--current",
            "marlin.txt",
        ],
    );
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stdout(&o).contains("M92 X79.997600"), "{}", stdout(&o));
}

#[test]
fn an_absurd_value_in_force_is_refused_not_built_on() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    diagnosis(d, "d.json", 30.0);
    for (controller, file, text, want) in [
        (
            "grblhal",
            "g.txt",
            "$100=0.000001\n",
            "$100 in force (--current) is 0.000001",
        ),
        (
            "marlin",
            "m.txt",
            "M92 X2000000\n",
            "M92 X in force (--current) is 2000000",
        ),
        (
            "marlin",
            "f.txt",
            "M92 X80\nM425 F1000 X0.01\n",
            "M425 F in force (--current) is 1000",
        ),
        (
            "klipper",
            "k.cfg",
            "[stepper_x]\nrotation_distance: 0.00004\n",
            "rotation_distance in force (--current) is 0.00004",
        ),
        (
            "linuxcnc",
            "l.ini",
            "[JOINT_0]\nCOMP_FILE = old.comp\nCOMP_FILE_TYPE = 1\n",
            "old.comp (in force) has a trim of 50 mm at 100 mm",
        ),
    ] {
        fs::write(d.join("old.comp"), "-100 0.001 -0.001\n100 50 0.001\n").unwrap();
        fs::write(d.join(file), text).unwrap();
        refused(
            d,
            &[
                "--diagnosis",
                "d.json",
                "--controller",
                controller,
                "--current",
                file,
            ],
            want,
        );
    }
}
