//! The README's demo section is what the demo prints today: `scripts/demo.sh`'s two commands,
//! `jdbb live` and `jdbb record` for a few seconds each against the QEMU firmware, then the
//! record's first lines, are run here as the script runs them, and every line the README shows
//! must come out with the same words, only its numbers free (sample counts, rates and times
//! differ from run to run; the pty's name too). The builds the script makes first are the test
//! suite's own.
use std::path::Path;
use std::process::Command;

use jdbb_tests::{jdbb_bin, qemu_available, qemu_elf, repo_root, Qemu};

/// A line with every number (digits, with their sign, decimal point and exponent) and the pty's
/// name replaced by `#`, so that lines of the same shape compare equal.
fn shape(line: &str) -> String {
    let line = line.replace("/dev/pts/", "/dev/pts/#");
    let mut out = String::new();
    let mut chars = line.chars().peekable();
    while let Some(c) = chars.next() {
        if c.is_ascii_digit() {
            while chars
                .peek()
                .is_some_and(|d| d.is_ascii_digit() || *d == '.')
            {
                chars.next();
            }
            if !out.ends_with('#') {
                out.push('#');
            }
        } else {
            out.push(c);
        }
    }
    out
}

/// Shapes of `lines`, a run of equal shapes kept once (`live` prints a line a second).
fn shapes<'a>(lines: impl Iterator<Item = &'a str>) -> Vec<String> {
    let mut out: Vec<String> = vec![];
    for l in lines {
        let s = shape(l);
        if out.last() != Some(&s) {
            out.push(s);
        }
    }
    out
}

/// The text block under the README's `## The demo` heading.
fn readme_demo() -> String {
    let readme = std::fs::read_to_string(repo_root().join("README.md")).unwrap();
    let section = readme
        .split("\n## The demo")
        .nth(1)
        .expect("the README has a `## The demo` section");
    let block = section
        .split("```text\n")
        .nth(1)
        .expect("the demo section shows what the demo prints in a ```text block");
    block.split("```").next().unwrap().to_string()
}

/// Run `jdbb args`; what it printed in the order a terminal shows it: its notes on stderr come
/// before its lines on stdout (`record` notes its start and the device, then sums up on stdout;
/// `live` prints only on stdout).
fn run(dir: &Path, args: &[&str]) -> String {
    let o = Command::new(jdbb_bin())
        .current_dir(dir)
        .args(args)
        .output()
        .unwrap();
    let (out, err) = (
        String::from_utf8_lossy(&o.stdout).into_owned(),
        String::from_utf8_lossy(&o.stderr).into_owned(),
    );
    assert!(o.status.success(), "jdbb {args:?}: {err}{out}");
    format!("{err}{out}")
}

#[test]
fn the_readme_demo_is_what_the_demo_prints() {
    let elf = qemu_elf("jdbb-firmware");
    if !qemu_available(&elf) {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::create_dir(d.join("out")).unwrap();
    let (_qemu, pty) = Qemu::start_with_pty(&elf);
    let pty = pty.to_str().unwrap().to_string();
    // As scripts/demo.sh 3 runs them.
    let mut printed = format!(
        "==> starting the firmware in QEMU\n    USART2 of the emulated board is {pty}\n==> jdbb live --port {pty} --seconds 3\n"
    );
    printed += &run(d, &["live", "--port", &pty, "--seconds", "3"]);
    printed += &format!("==> jdbb record --port {pty} --out out/demo.csv --seconds 3 --force\n");
    printed += &run(
        d,
        &[
            "record",
            "--port",
            &pty,
            "--out",
            "out/demo.csv",
            "--seconds",
            "3",
            "--force",
        ],
    );
    let csv = std::fs::read_to_string(d.join("out/demo.csv")).unwrap();
    let samples = csv.lines().filter(|l| !l.starts_with('#')).count() - 1;
    printed += &format!("==> out/demo.csv: {samples} samples; first lines:\n");
    for l in csv.lines().take(4) {
        printed += l;
        printed += "\n";
    }
    println!("{printed}");
    let (shown, got) = (shapes(readme_demo().lines()), shapes(printed.lines()));
    assert_eq!(
        shown, got,
        "README.md's demo section is not what the demo prints today (numbers aside):\n{printed}"
    );
    // The words the section's prose relies on.
    assert!(
        printed.contains("clock emulated")
            && printed.contains("# instrument_serial: 000000000000000000000000")
    );
}
