//! The volumetric test through the whole chain (issue 29, item 2), each step the program a person
//! runs, as `qemu_scenario.rs` does for a plane test:
//!
//! 1. `jdbb plan --volumetric` writes one program (LinuxCNC) and one plan.json: xy cones at three
//!    heights, then zx and yz 220° arcs, joined by moves along the shell;
//! 2. the independent G-code machine (`jdbb_tests::gmachine`) runs that program with errors on
//!    all three axes (three squarenesses, three scales, play on each axis, Z's unequal at its two
//!    ends), a 97 % feed override, the device clock 37 ppm fast and 0.2 µm of noise, and turns
//!    the run into the encoders' counts: a scenario file (`jdbb_core::scenario`);
//! 3. the QEMU build of the firmware plays the scenario as its encoders (the same firmware as for
//!    a plane test: a scenario is counts, whatever the motion), computes D on chip and streams
//!    over USART2;
//! 4. `jdbb record --plan plan.json` records the run, showing its progress through the five
//!    elements, and stops by itself after the program's end.
//!
//! The record must be the scenario, exactly (every sample, in order, on time, every count the
//! scenario's, every D the host reference's within the on-chip budget), and read back with every
//! element present: one stretch of D at the elements' ball distance per element, in the plan's
//! order, each as long as the plan's arcs and dwells on it take at the overridden feed. (The joint
//! diagnosis of a volumetric record is not built yet: the record is checked by its elements.)
use std::process::{Command, Stdio};

use jdbb::plan::{Plan, Plane};
use jdbb::volumetric::elements::on_circle_s;
use jdbb_tests::gmachine::{
    Axis, BacklashEnds, Dialect, MachineErrors, SimConfig, Simulation, Squareness,
};
use jdbb_tests::{check_record_is_scenario, jdbb_bin, qemu_available, qemu_elf, Qemu};

const CENTRE: &str = "100,50,-20";
const RATE_HZ: u32 = 2_000;
const FEED_MM_MIN: f64 = 5000.0;
const OVERRIDE_PCT: f64 = 97.0;

#[test]
fn a_volumetric_plan_plays_through_qemu_and_records_every_element() {
    let elf = qemu_elf("jdbb-firmware");
    if !qemu_available(&elf) {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let plan_dir = dir.path().join("plan");

    // 1. The program.
    let out = Command::new(jdbb_bin())
        .args([
            "plan",
            "--volumetric",
            "--distance",
            "90",
            "--feed",
            &FEED_MM_MIN.to_string(),
            "--centre",
            CENTRE,
            "--out",
        ])
        .arg(&plan_dir)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let plan = Plan::read(&plan_dir.join("plan.json")).unwrap();
    let planes: Vec<Plane> = plan.circles.iter().map(|c| c.plane).collect();
    assert_eq!(
        planes,
        [Plane::Xy, Plane::Xy, Plane::Xy, Plane::Zx, Plane::Yz]
    );

    // 2. The machine runs it; the instrument's counts become the scenario.
    let program = std::fs::read_to_string(plan_dir.join("ballbar.ngc")).unwrap();
    let mut cfg = SimConfig::new(Dialect::LinuxCnc, [100.0, 50.0, -20.0]);
    let lean = |axis, by, um_per_m| Squareness { axis, by, um_per_m };
    cfg.errors = MachineErrors {
        backlash_um: [6.0, 4.0, 0.0],
        backlash_ends: [
            None,
            None,
            Some(BacklashEnds {
                neg_end_mm: -20.0,
                neg_um: 3.0,
                pos_end_mm: 70.0,
                pos_um: 5.0,
            }),
        ],
        scale_um_per_m: [30.0, -20.0, 25.0],
        squareness: vec![
            lean(Axis::X, Axis::Y, 40.0),
            lean(Axis::Y, Axis::Z, -60.0),
            lean(Axis::Z, Axis::X, 45.0),
        ],
        setup_offset_um: [25.0, -15.0, 10.0],
        ..MachineErrors::default()
    };
    cfg.machine.feed_override_pct = OVERRIDE_PCT;
    cfg.instrument.sample_rate_hz = f64::from(RATE_HZ);
    cfg.instrument.clock_ppm = 37.0;
    cfg.instrument.noise_um = 0.2;
    cfg.instrument.start_delay_s = 2.5;
    cfg.instrument.tail_s = 1.0;
    cfg.instrument.seed = 29;
    let a_min_mm_s2 = cfg.machine.accel_mm_s2.into_iter().fold(f64::MAX, f64::min);
    let sim = Simulation::new(&program, cfg).unwrap();
    let scenario = dir.path().join("scenario.bin");
    let mut f = std::io::BufWriter::new(std::fs::File::create(&scenario).unwrap());
    let header = sim.write_scenario(&mut f).unwrap();
    drop(f);
    let n = header.n_samples as u64;
    assert_eq!(header.period_us, 1_000_000 / RATE_HZ);

    // 3. The firmware plays it.
    let (_qemu, pty) = Qemu::start_with_scenario(&elf, &scenario);

    // 4. Record with the plan: it stops by itself after the program's end.
    let rec = dir.path().join("rec.csv");
    let done = Command::new(jdbb_bin())
        .args(["record", "--rate", &RATE_HZ.to_string(), "--port"])
        .arg(&pty)
        .arg("--out")
        .arg(&rec)
        .arg("--plan")
        .arg(plan_dir.join("plan.json"))
        .args(["--seconds", "900"])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap()
        .wait_with_output()
        .unwrap();
    let summary = format!(
        "{}{}",
        String::from_utf8_lossy(&done.stdout),
        String::from_utf8_lossy(&done.stderr)
    );
    println!("{summary}");
    assert!(done.status.success(), "jdbb record: {summary}");
    assert!(
        summary.contains("the plan's program ended") && summary.contains("circle 5/5, arcs"),
        "no automatic stop or progress through the five elements: {summary}"
    );
    assert!(!summary.contains("cycle start was missed"), "{summary}");
    for clean in ["lost 0 (device dropped 0)", "corrupt frames 0", "resets 0"] {
        assert!(summary.contains(clean), "not '{clean}': {summary}");
    }

    // The record is the scenario: every sample, in order, on time, with its counts and D.
    let expected: Vec<_> = sim.samples().map(|s| s.unwrap().row).collect();
    let text = std::fs::read_to_string(&rec).unwrap();
    let (d_mm, _) = check_record_is_scenario(&text, &expected, u64::from(header.period_us), None);
    let rows = d_mm.len() as u64;
    println!("record: {rows} samples at {RATE_HZ} Hz of a scenario of {n}");
    assert!(rows >= n, "only {rows} samples of {n} recorded");

    // Every element, in the plan's order: a stretch of at least 1 s within 30 µm of the ball
    // distance (the errors move D by a few µm), as long as the element's arcs at the overridden
    // feed and its dwells on the device's clock, and at most 4 v/a longer, a the smallest of the
    // axes' acceleration limits: the ccw and the cw run each start and end at rest, and the G-code
    // machine's planner takes an arc's speed up and down at less than that limit where the
    // tangent turns (measured: 0.66 s on each cone, 0.56 s on the zx arc, 1.10 s on the yz arc at
    // 5000 mm/min, against 4 v/a = 1.08 s and 2 % of the planned time).
    let d_ball = plan.circles[0].d_mm;
    assert!(plan.circles.iter().all(|c| (c.d_mm - d_ball).abs() < 1e-3));
    let mut stretches = vec![];
    let mut start = None;
    for (i, d) in d_mm.iter().enumerate() {
        match ((d - d_ball).abs() < 0.03, start) {
            (true, None) => start = Some(i),
            (false, Some(s)) => {
                stretches.push((s, i - 1));
                start = None;
            }
            _ => {}
        }
    }
    stretches.retain(|&(a, b)| (b - a) as f64 / f64::from(RATE_HZ) >= 1.0);
    assert_eq!(
        stretches.len(),
        plan.circles.len(),
        "stretches at D {d_ball} mm: {stretches:?}"
    );
    let clock = 1.0 + 37e-6;
    for (k, &(a, b)) in stretches.iter().enumerate() {
        let seen_s = (b - a) as f64 / f64::from(RATE_HZ);
        let (moving_s, dwell_s) = on_circle_s(&plan, k).unwrap();
        let planned_s = (moving_s / (OVERRIDE_PCT / 100.0) + dwell_s) * clock;
        println!(
            "element {k} ({:?}, H {} mm): {seen_s:.3} s at D, planned {planned_s:.3} s",
            plan.circles[k].plane, plan.circles[k].height_mm
        );
        let v_mm_s = FEED_MM_MIN / 60.0 * OVERRIDE_PCT / 100.0;
        let extra_s = seen_s - planned_s;
        assert!(
            extra_s > -0.02 * planned_s && extra_s < 0.02 * planned_s + 4.0 * v_mm_s / a_min_mm_s2,
            "element {k} ({:?}): {seen_s:.3} s at D, the plan {planned_s:.3} s",
            plan.circles[k].plane
        );
    }
}
