//! Run a ballbar program on the independent G-code machine simulator (`jdbb_tests::gmachine`) and
//! write what the J-DBB records, as `jdbb record` writes it (`seq,t_us,enc1,enc2,d_mm`). This is
//! how the README's example record `data/examples/ballbar-backlash.csv` was made:
//!
//! ```text
//! jdbb plan --radius 90 --feed 2000 --centre 100,50,-20 --out out/plan1 --force
//! cargo run --release -p jdbb-tests --example gmachine_record -- \
//!   --program out/plan1/ballbar.ngc --centre 100,50,-20 --rate 200 --backlash-x-um 6 \
//!   --feed-override-pct 98 --clock-ppm 37 --noise-um 0.2 --start-delay-s 4 --seed 3 \
//!   --plan-id 354e9a61645853a2 --out data/examples/ballbar-backlash.csv
//! ```
//!
//! Options (each `--name value`): `--program FILE` (LinuxCNC dialect; required), `--centre X,Y,Z`
//! (mm, where the table ball is in program coordinates; required), `--out FILE` (the record),
//! `--scenario FILE` (the same run as a QEMU scenario, `jdbb_core::scenario`, for
//! `scripts/qemu-run.sh --scenario`; one of the two is required),
//! `--rate` (Hz, 1000), `--backlash-x-um`, `--backlash-y-um`, `--squareness-xy-um-per-m`,
//! `--drift-um-per-min`, `--setup-offset-um X,Y,Z`, `--feed-override-pct` (100), `--clock-ppm`,
//! `--noise-um`, `--start-delay-s` (3), `--seed`, `--plan-id ID` (the plan's id, which
//! `jdbb simulate --plan` prints, written as the `# plan_id:` line `jdbb record --plan` writes). It prints the truth (cycle start, feed) on
//! stderr.
use std::collections::HashMap;
use std::io::Write;
use std::process::ExitCode;

use jdbb_tests::gmachine::{
    Axis, Dialect, MachineErrors, SimConfig, Simulation, Squareness, CSV_HEADER,
};

fn triple(s: &str) -> Result<[f64; 3], String> {
    let v: Vec<f64> = s
        .split(',')
        .map(|p| p.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .map_err(|e| format!("{s}: {e}"))?;
    v.try_into().map_err(|_| format!("{s}: expected X,Y,Z"))
}

fn run() -> Result<(), String> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if !args.len().is_multiple_of(2) {
        return Err("options come as --name value pairs".into());
    }
    let mut opt: HashMap<&str, &str> = HashMap::new();
    for pair in args.chunks(2) {
        let name = pair[0]
            .strip_prefix("--")
            .ok_or_else(|| format!("{}: expected --name", pair[0]))?;
        opt.insert(name, &pair[1]);
    }
    let num = |name: &str, default: f64| -> Result<f64, String> {
        opt.get(name).map_or(Ok(default), |v| {
            v.parse().map_err(|e| format!("--{name} {v}: {e}"))
        })
    };
    let need = |name: &str| {
        opt.get(name)
            .copied()
            .ok_or(format!("--{name} is required"))
    };
    let program = std::fs::read_to_string(need("program")?)
        .map_err(|e| format!("{}: {e}", need("program").unwrap_or_default()))?;
    let mut cfg = SimConfig::new(Dialect::LinuxCnc, triple(need("centre")?)?);
    let mut errors = MachineErrors {
        drift_um_per_min: num("drift-um-per-min", 0.0)?,
        ..MachineErrors::default()
    };
    errors.backlash_um = [num("backlash-x-um", 0.0)?, num("backlash-y-um", 0.0)?, 0.0];
    if let Some(s) = opt.get("setup-offset-um") {
        errors.setup_offset_um = triple(s)?;
    }
    let sq = num("squareness-xy-um-per-m", 0.0)?;
    if sq != 0.0 {
        errors.squareness.push(Squareness {
            axis: Axis::X,
            by: Axis::Y,
            um_per_m: sq,
        });
    }
    cfg.errors = errors;
    cfg.machine.feed_override_pct = num("feed-override-pct", 100.0)?;
    cfg.instrument.sample_rate_hz = num("rate", 1000.0)?;
    cfg.instrument.clock_ppm = num("clock-ppm", 0.0)?;
    cfg.instrument.noise_um = num("noise-um", 0.0)?;
    cfg.instrument.start_delay_s = num("start-delay-s", 3.0)?;
    cfg.instrument.seed = num("seed", 0.0)? as u64;
    let sim = Simulation::new(&program, cfg).map_err(|e| e.to_string())?;
    if let Some(path) = opt.get("scenario") {
        // Write to a new file beside it and rename: a failed run leaves no half scenario.
        let part = format!("{path}.partial");
        let mut f = std::io::BufWriter::new(
            std::fs::File::create(&part).map_err(|e| format!("{part}: {e}"))?,
        );
        let h = sim
            .write_scenario(&mut f)
            .map_err(|e| format!("{path}: {e}"))?;
        f.flush().map_err(|e| format!("{part}: {e}"))?;
        drop(f);
        std::fs::rename(&part, path).map_err(|e| format!("{path}: {e}"))?;
        eprintln!(
            "wrote {path}: scenario of {} samples every {} µs ({:.1} s); truth: cycle start at \
             t_us {:.0} after Start, feed factor {}, clock {} ppm",
            h.n_samples,
            h.period_us,
            f64::from(h.n_samples) * f64::from(h.period_us) * 1e-6,
            sim.device_us(sim.trajectory().cycle_start_s) - sim.config().instrument.t0_us as f64,
            sim.config().machine.feed_override_pct / 100.0,
            sim.config().instrument.clock_ppm
        );
        if !opt.contains_key("out") {
            return Ok(());
        }
    }
    // Row by row (constant memory, for records of tens of millions of samples).
    let out = need("out")?;
    let mut f =
        std::io::BufWriter::new(std::fs::File::create(out).map_err(|e| format!("{out}: {e}"))?);
    if let Some(id) = opt.get("plan-id") {
        // The line `jdbb record --plan` writes first, which `jdbb diagnose` checks the plan by.
        writeln!(f, "# plan_id: {id}").map_err(|e| format!("{out}: {e}"))?;
    }
    f.write_all(CSV_HEADER.as_bytes())
        .map_err(|e| format!("{out}: {e}"))?;
    let mut n = 0u64;
    for s in sim.samples() {
        let row = s.map_err(|e| e.to_string())?.row;
        row.write_csv_line(&mut f)
            .map_err(|e| format!("{out}: {e}"))?;
        n += 1;
    }
    f.flush().map_err(|e| format!("{out}: {e}"))?;
    eprintln!(
        "wrote {out}: {n} samples; truth: cycle start at t_us {:.0}, feed factor {}, clock {} ppm",
        sim.device_us(sim.trajectory().cycle_start_s),
        sim.config().machine.feed_override_pct / 100.0,
        sim.config().instrument.clock_ppm
    );
    Ok(())
}

fn main() -> ExitCode {
    match run() {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::from(2)
        }
    }
}
