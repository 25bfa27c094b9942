//! The whole chain with a hidden effect (issue 8 §5), each step the program a person runs:
//!
//! 1. `jdbb plan` writes the ballbar program (LinuxCNC) and plan.json;
//! 2. the independent G-code machine simulator (`jdbb_tests::gmachine`) runs that program with a
//!    hidden 6 µm X backlash and a 20 µm/m XY squareness error, a 97 % feed override, acceleration limits, an unknown start, the
//!    device clock 37 ppm fast, 0.2 µm noise and a wandering lean, and turns the run into the
//!    encoders' counts: a scenario file (`jdbb_core::scenario`);
//! 3. the QEMU build of the firmware plays the scenario as its encoders (read over semihosting,
//!    as `scripts/qemu-run.sh --scenario` starts it), computes D on chip and streams over USART2;
//! 4. `jdbb record --rate 5000 --plan plan.json` records the run, showing its progress, and
//!    stops by itself after the program's end (issue 17);
//! 5. `jdbb diagnose --record --plan --json` must name the backlash and the squareness, each
//!    by the one tolerance rule (`jdbb_tests::tolerance`: within 5 % and within 1 % + 3σ, σ
//!    under 10 %), and no other machine effect.
//!
//! The record itself must be the scenario, exactly: at least 100 000 samples at 5 kHz, `seq` from
//! 0 without a gap, `t_us` = 200 µs × `seq`, nothing lost or dropped, every count the scenario's,
//! every D the host reference's within the on-chip budget.
use std::process::{Command, Stdio};

use jdbb_tests::gmachine::{Axis, Dialect, MachineErrors, SimConfig, Simulation, Squareness};
use jdbb_tests::{check_record_is_scenario, jdbb_bin, qemu_available, qemu_elf, Qemu};

const CENTRE: &str = "100,50,-20";
const RATE_HZ: u32 = 5_000;
const BACKLASH_X_UM: f64 = 6.0;
const SQUARENESS_XY_UM_PER_M: f64 = 20.0;

#[test]
fn plan_scenario_qemu_record_diagnose_names_the_hidden_effects() {
    let elf = qemu_elf("jdbb-firmware");
    if !qemu_available(&elf) {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let plan_dir = dir.path().join("plan");

    // 1. The program.
    let out = Command::new(jdbb_bin())
        .args([
            "plan", "--radius", "90", "--feed", "4000", "--centre", CENTRE, "--out",
        ])
        .arg(&plan_dir)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );

    // 2. The machine runs it; the instrument's counts become the scenario.
    let program = std::fs::read_to_string(plan_dir.join("ballbar.ngc")).unwrap();
    let mut cfg = SimConfig::new(Dialect::LinuxCnc, [100.0, 50.0, -20.0]);
    cfg.errors = MachineErrors {
        backlash_um: [BACKLASH_X_UM, 0.0, 0.0],
        squareness: vec![Squareness {
            axis: Axis::X,
            by: Axis::Y,
            um_per_m: SQUARENESS_XY_UM_PER_M,
        }],
        setup_offset_um: [25.0, -15.0, 0.0],
        ..MachineErrors::default()
    };
    cfg.machine.feed_override_pct = 97.0;
    cfg.instrument.sample_rate_hz = f64::from(RATE_HZ);
    cfg.instrument.clock_ppm = 37.0;
    cfg.instrument.noise_um = 0.2;
    cfg.instrument.start_delay_s = 2.5;
    cfg.instrument.tail_s = 1.0;
    cfg.instrument.seed = 11;
    let sim = Simulation::new(&program, cfg).unwrap();
    let scenario = dir.path().join("scenario.bin");
    let mut f = std::io::BufWriter::new(std::fs::File::create(&scenario).unwrap());
    let header = sim.write_scenario(&mut f).unwrap();
    drop(f);
    let n = header.n_samples as u64;
    assert_eq!(header.period_us, 1_000_000 / RATE_HZ);
    assert!(n >= 100_000, "the scenario is only {n} samples long");

    // 3. The firmware plays it.
    let (_qemu, pty) = Qemu::start_with_scenario(&elf, &scenario);

    // 4. Record with the plan: it stops by itself after the program's end (the scenario then
    // holds the counters, so D stands at the end level).
    let rec = dir.path().join("rec.csv");
    let recorder = Command::new(jdbb_bin())
        .args(["record", "--rate", &RATE_HZ.to_string(), "--port"])
        .arg(&pty)
        .arg("--out")
        .arg(&rec)
        .arg("--plan")
        .arg(plan_dir.join("plan.json"))
        .args(["--seconds", "400"])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let done = recorder.wait_with_output().unwrap();
    let summary = format!(
        "{}{}",
        String::from_utf8_lossy(&done.stdout),
        String::from_utf8_lossy(&done.stderr)
    );
    println!("{summary}");
    assert!(done.status.success(), "jdbb record: {summary}");
    assert!(
        summary.contains("the plan's program ended") && summary.contains("circle 1/1, arcs"),
        "no automatic stop or progress line: {summary}"
    );
    assert!(!summary.contains("cycle start was missed"), "{summary}");
    for clean in ["lost 0 (device dropped 0)", "corrupt frames 0", "resets 0"] {
        assert!(summary.contains(clean), "not '{clean}': {summary}");
    }

    // The record is the scenario: every sample, in order, on time, with its counts and D.
    let expected: Vec<_> = sim.samples().map(|s| s.unwrap().row).collect();
    let text = std::fs::read_to_string(&rec).unwrap();
    // QEMU's chip ID is all zero: the serial the device reported, right after the header.
    let (d_mm, worst_nm) =
        check_record_is_scenario(&text, &expected, 200, Some("000000000000000000000000"));
    let rows = d_mm.len() as u64;
    println!("record: {rows} samples at {RATE_HZ} Hz, max |D_chip − D_host| = {worst_nm:.2} nm");
    assert!(rows >= 100_000 && rows >= n, "only {rows} samples recorded");

    // 5. The diagnosis from the record and the plan alone.
    let out = Command::new(jdbb_bin())
        .args(["diagnose", "--json", "--record"])
        .arg(&rec)
        .arg("--plan")
        .arg(plan_dir.join("plan.json"))
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let json: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let sync = &json["sync"];
    // The feed the machine ran on the record's clock, and cycle start within 10 ms.
    let feed = 97.0 * (1.0 + 37e-6);
    let measured = sync["feed_percent"].as_f64().unwrap();
    assert!(
        (measured - feed).abs() < 0.05,
        "feed {measured} % vs {feed} %"
    );
    let start_us = sim.device_us(sim.trajectory().cycle_start_s);
    let found_us = sync["cycle_start_device_us"].as_f64().unwrap();
    assert!(
        (found_us - start_us).abs() < 10_000.0,
        "cycle start {found_us} µs vs {start_us} µs"
    );
    let machine: Vec<&serde_json::Value> = json["effects"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|e| e["setup"] == false)
        .collect();
    let mut names: Vec<&str> = machine
        .iter()
        .map(|e| e["name"].as_str().unwrap())
        .collect();
    names.sort_unstable();
    assert_eq!(names, ["backlash_x", "squareness_xy"], "{json:#}");
    for (name, truth) in [
        ("backlash_x", BACKLASH_X_UM),
        ("squareness_xy", SQUARENESS_XY_UM_PER_M),
    ] {
        let e = machine.iter().find(|e| e["name"] == name).unwrap();
        let (value, sigma) = (e["value"].as_f64().unwrap(), e["sigma"].as_f64().unwrap());
        println!("{name} {value:.4} ± {sigma:.4} (hidden {truth})");
        jdbb_tests::tolerance::assert_unbiased(name, value, sigma, truth, 0.0, &json.to_string());
    }
    println!("feed {measured:.3} % (truth {feed:.3} %)");
}
