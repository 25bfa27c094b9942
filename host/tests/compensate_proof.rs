//! The compensation's sign conventions, proven rather than asserted (issue 10): a round trip on
//! the project's own simulator (`jdbb::simulate`, the fit's own effect models on the
//! fit's `Path`), so the *machine's* conventions here are the diagnosis' own. What this proves is
//! the controller side — that each emitted setting, applied with the controller's documented
//! semantics, removes what the diagnosis measured. That the diagnosis measured the machine's
//! real error with the right sign, phase and table positions is checked against the independent
//! G-code machine in `tests/tests/compensate_truth.rs` (issue 21).
//!
//! For each controller: a simulated machine with known errors runs the circular test under the
//! settings in force; `jdbb`'s diagnosis and `compensate` give new settings; the text they emit
//! (INI lines, comp tables, `$n=` lines, M-codes, `SET_SKEW`) is parsed *here* and applied to the
//! commanded motion with that controller's documented semantics, written below from
//! `shared/notes/controllers.md` and the controllers' sources — not by inverting the emitter:
//!
//! - LinuxCNC `BACKLASH` B: motor = command + (B/2)·(held sign of the commanded velocity).
//! - LinuxCNC `COMP_FILE`: triplets `nominal a b`; type 0 stores `nominal − a`, `nominal − b`,
//!   type 1 stores a, b; the trim of the direction of motion, linearly interpolated at the
//!   commanded joint position (end values held), is added to the motor command.
//! - LinuxCNC `matrixkins`: joint_i = Σ_j C_ij·coordinate_j (C_ii = 1).
//! - grblHAL `$16n` and Marlin `M425` (F·distance): at each reversal a move of the full distance
//!   in the new direction (grblHAL rounds it to whole steps).
//! - Marlin `M852` and Klipper (`SET_SKEW` lengths through `calc_skew_factor`):
//!   x' = x − y·xy − z·(xz − xy·yz), y' = y − z·yz.
//! - Steps/mm (`M92`, `$10n`) and Klipper `rotation_distance`: the motor moves the command
//!   times new/old steps per mm (old/new rotation distance).
//!
//! The machine's errors act on the motor path; the ball bar measures the result (0.3 µm noise,
//! 0.1 µm resolution, a new noise seed after compensation), which is diagnosed against the
//! commanded path again. Each compensated effect must then be indistinguishable from zero: its
//! value, fitted with the first diagnosis' effects, within 3 σ_c with σ_c = √(σ_before² +
//! σ_after²) (what remains is the first estimate's own error, σ_before, as measured by a test with
//! error σ_after), and the re-diagnosis must either not select it or find it within 3 σ_c. An
//! effect no setting can take (servo mismatch) must still be there: the test can fail.
// Index loops over the axes mirror the equations.
#![allow(clippy::needless_range_loop)]
use std::path::Path as FsPath;

use jdbb::compensate::{plan, Controller, Current, Options, Placement, Plan};
use jdbb::diagnose::{diagnose, Diagnosis, Options as DiagOptions};
use jdbb::model::{Effect, EffectSet, ExactModel, Path};
use jdbb::numerics::lsq::{least_squares, LsqOptions};
use jdbb::report::document::DiagnosisDoc;
use jdbb::report::to_json;
use jdbb::simulate::{distances_mm, measure, nominal_path, parse_effect, EffectValue, PathSpec};

/// Settings in force on the simulated controller, parsed from emitted or `--current` text.
#[derive(Debug, Clone)]
struct Settings {
    /// LinuxCNC BACKLASH per joint, mm.
    linuxcnc_backlash_mm: [f64; 3],
    /// LinuxCNC comp tables per joint: (nominal, forward trim, reverse trim) as loaded.
    comp: [Option<Vec<(f64, f64, f64)>>; 3],
    /// matrixkins C (row = joint).
    matrix: [[f64; 3]; 3],
    /// grblHAL $16n: the full distance added at each reversal, mm.
    grbl_backlash_mm: [f64; 3],
    /// Marlin M425 F and distances: F × distance is added at each reversal.
    marlin_f: f64,
    marlin_mm: [f64; 3],
    /// grblHAL: steps per mm the reversal move is rounded to (None: not rounded).
    reversal_steps_per_mm: Option<f64>,
    /// Skew factors xy, xz, yz (Marlin M852 I J K, Klipper).
    skew: [f64; 3],
    /// Motor travel per commanded mm relative to the test's first settings.
    travel_ratio: [f64; 3],
}

impl Default for Settings {
    fn default() -> Self {
        Settings {
            linuxcnc_backlash_mm: [0.0; 3],
            comp: [None, None, None],
            matrix: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            grbl_backlash_mm: [0.0; 3],
            marlin_f: 0.0,
            marlin_mm: [0.0; 3],
            reversal_steps_per_mm: None,
            skew: [0.0; 3],
            travel_ratio: [1.0; 3],
        }
    }
}

fn axis_index(c: char) -> usize {
    match c.to_ascii_lowercase() {
        'x' => 0,
        'y' => 1,
        'z' => 2,
        other => panic!("axis {other}"),
    }
}

/// Klipper's calc_skew_factor (skew_correction.py), as controllers.md gives Marlin's definition.
fn calc_skew_factor(ac: f64, bd: f64, ad: f64) -> f64 {
    let side = (2.0 * ac * ac + 2.0 * bd * bd - 4.0 * ad * ad).sqrt() / 2.0;
    (std::f64::consts::FRAC_PI_2 - ((ac * ac - side * side - ad * ad) / (2.0 * side * ad)).acos())
        .tan()
}

/// G-code words `M425 F1 X0.01` → [('M', 425), ('F', 1), ('X', 0.01)].
fn words(line: &str) -> Vec<(char, f64)> {
    line.split_whitespace()
        .filter_map(|w| {
            let mut c = w.chars();
            let l = c.next()?.to_ascii_uppercase();
            Some((l, c.as_str().parse().ok()?))
        })
        .collect()
}

/// Steps-per-mm style settings of the first and the new text: old/new → travel ratio.
#[derive(Debug, Clone, Default)]
struct StepsPerMm([Option<f64>; 3]);

/// Apply the lines of `text` (in `controller`'s syntax) to `s`; `files` are the comp tables.
/// `steps` records steps/mm (or rotation distance) seen, to turn into a travel ratio.
fn apply_text(
    controller: Controller,
    lines: &[String],
    files: &[(String, String)],
    s: &mut Settings,
    steps: &mut StepsPerMm,
) {
    let mut joint: Option<usize> = None;
    let mut comp_name: [Option<String>; 3] = [None, None, None];
    let mut comp_type = [1u8; 3];
    let mut section = String::new();
    for line in lines {
        let t = line.trim();
        match controller {
            Controller::LinuxCnc => {
                if let Some(n) = t.strip_prefix("[JOINT_") {
                    joint = Some(n.trim_end_matches(']').parse().unwrap());
                } else if let Some(rest) = t.strip_prefix("setp matrixkins.C_") {
                    let (ij, v) = rest.split_once(' ').unwrap();
                    let ij: Vec<char> = ij.chars().collect();
                    s.matrix[axis_index(ij[0])][axis_index(ij[1])] = v.trim().parse().unwrap();
                } else if let Some((k, v)) = t.split_once('=') {
                    let j = joint.expect("a key inside a [JOINT_n] section");
                    match k.trim() {
                        "BACKLASH" => s.linuxcnc_backlash_mm[j] = v.trim().parse().unwrap(),
                        "COMP_FILE" => comp_name[j] = Some(v.trim().to_string()),
                        "COMP_FILE_TYPE" => comp_type[j] = v.trim().parse().unwrap(),
                        _ => {}
                    }
                }
            }
            Controller::GrblHal => {
                if let Some((k, v)) = t.strip_prefix('$').and_then(|r| r.split_once('=')) {
                    let n: usize = k.parse().unwrap();
                    let v: f64 = v.parse().unwrap();
                    match n {
                        160..=162 => s.grbl_backlash_mm[n - 160] = v,
                        100..=102 => steps.0[n - 100] = Some(v),
                        _ => {}
                    }
                }
            }
            Controller::Marlin => {
                let w = words(t);
                match w.first() {
                    Some(('M', m)) if *m == 425.0 => {
                        // M425 sets only the words it has.
                        for (l, v) in &w[1..] {
                            match l {
                                'F' => s.marlin_f = *v,
                                'X' | 'Y' | 'Z' => s.marlin_mm[axis_index(*l)] = *v,
                                _ => {}
                            }
                        }
                    }
                    Some(('M', m)) if *m == 852.0 => {
                        for (l, v) in &w[1..] {
                            match l {
                                'I' | 'S' => s.skew[0] = *v,
                                'J' => s.skew[1] = *v,
                                'K' => s.skew[2] = *v,
                                _ => {}
                            }
                        }
                    }
                    Some(('M', m)) if *m == 92.0 => {
                        for (l, v) in &w[1..] {
                            if matches!(l, 'X' | 'Y' | 'Z') {
                                steps.0[axis_index(*l)] = Some(*v);
                            }
                        }
                    }
                    _ => {}
                }
            }
            Controller::Klipper => {
                if let Some(rest) = t.strip_prefix("SET_SKEW ") {
                    for part in rest.split_whitespace() {
                        let (plane, lengths) = part.split_once('=').unwrap();
                        let l: Vec<f64> = lengths.split(',').map(|x| x.parse().unwrap()).collect();
                        let k = calc_skew_factor(l[0], l[1], l[2]);
                        match plane {
                            "XY" => s.skew[0] = k,
                            "XZ" => s.skew[1] = k,
                            "YZ" => s.skew[2] = k,
                            other => panic!("plane {other}"),
                        }
                    }
                } else if t.starts_with('[') || t.starts_with("#*# [") {
                    section = t
                        .trim_start_matches("#*# ")
                        .trim_matches(|c| c == '[' || c == ']')
                        .to_string();
                } else if section.starts_with("skew_correction") && t.contains("_skew") {
                    // A saved profile (SKEW_PROFILE LOAD applies its factors).
                    let (k, v) = t.trim_start_matches("#*# ").split_once('=').unwrap();
                    let v: f64 = v.trim().parse().unwrap();
                    match k.trim() {
                        "xy_skew" => s.skew[0] = v,
                        "xz_skew" => s.skew[1] = v,
                        "yz_skew" => s.skew[2] = v,
                        other => panic!("{other}"),
                    }
                } else if let Some(v) = t.strip_prefix("rotation_distance:") {
                    let axis = axis_index(section.chars().last().unwrap());
                    // steps per mm ∝ 1 / rotation_distance
                    steps.0[axis] = Some(1.0 / v.trim().parse::<f64>().unwrap());
                }
            }
            // The industrial controls are proven on the G-code machine
            // (`tests/tests/compensate_truth.rs`, `industrial_*`), not in this round trip.
            Controller::Fanuc | Controller::Sinumerik | Controller::Heidenhain => {
                panic!("{controller:?}: not in this round trip")
            }
        }
    }
    for j in 0..3 {
        if let Some(name) = &comp_name[j] {
            let text = &files.iter().find(|(n, _)| n == name).expect("comp file").1;
            let mut table = vec![];
            for l in text.lines() {
                let v: Vec<f64> = l.split_whitespace().map(|x| x.parse().unwrap()).collect();
                assert_eq!(v.len(), 3, "a comp file line is a triplet: {l}");
                // usrmotintf.cc: type 0 converts actual positions to trims.
                if comp_type[j] == 0 {
                    table.push((v[0], v[0] - v[1], v[0] - v[2]));
                } else {
                    table.push((v[0], v[1], v[2]));
                }
            }
            assert!(table.len() <= 256);
            assert!(
                table.windows(2).all(|w| w[0].0 < w[1].0),
                "nominals increase"
            );
            s.comp[j] = Some(table);
        }
    }
}

/// Held sign of the velocity of coordinate `k` along `p` (LinuxCNC: "not moving, use whatever
/// was there before"; the first motion sets it).
fn held_directions(p: &[[f64; 3]], k: usize) -> Vec<f64> {
    let n = p.len();
    let mut raw = vec![0.0; n];
    for i in 0..n {
        let (a, b) = (i.saturating_sub(1), (i + 1).min(n - 1));
        let d = p[b][k] - p[a][k];
        raw[i] = if d > 1e-12 {
            1.0
        } else if d < -1e-12 {
            -1.0
        } else {
            0.0
        };
    }
    let mut held = raw.iter().cloned().find(|d| *d != 0.0).unwrap_or(1.0);
    raw.iter()
        .map(|&d| {
            if d != 0.0 {
                held = d;
            }
            held
        })
        .collect()
}

/// Trim of a LinuxCNC comp table at `pos` in direction `dir` (linear, end values held).
fn comp_trim(table: &[(f64, f64, f64)], pos: f64, dir: f64) -> f64 {
    let pick = |e: &(f64, f64, f64)| if dir > 0.0 { e.1 } else { e.2 };
    if pos <= table[0].0 {
        return pick(&table[0]);
    }
    if pos >= table[table.len() - 1].0 {
        return pick(&table[table.len() - 1]);
    }
    let i = table.partition_point(|e| e.0 <= pos) - 1;
    let (a, b) = (&table[i], &table[i + 1]);
    let f = (pos - a.0) / (b.0 - a.0);
    pick(a) + f * (pick(b) - pick(a))
}

/// The motor path (relative to the table ball) for the commanded path `cmd` under `s`, and the
/// joint command before the screw/backlash corrections (whose direction and speed the motors
/// have: a correction only adds motion in the direction of motion); the table ball sits at
/// machine position `ball_mm`.
fn motor_path(cmd: &[[f64; 3]], s: &Settings, ball_mm: [f64; 3]) -> (Vec<[f64; 3]>, Vec<[f64; 3]>) {
    // Cartesian → joint: skew (Marlin, Klipper), then matrixkins.
    let joint: Vec<[f64; 3]> = cmd
        .iter()
        .map(|c| {
            let m = [c[0] + ball_mm[0], c[1] + ball_mm[1], c[2] + ball_mm[2]];
            let (xy, xz, yz) = (s.skew[0], s.skew[1], s.skew[2]);
            let k = [
                m[0] - m[1] * xy - m[2] * (xz - xy * yz),
                m[1] - m[2] * yz,
                m[2],
            ];
            let mut j = [0.0; 3];
            for r in 0..3 {
                j[r] = (0..3).map(|c| s.matrix[r][c] * k[c]).sum();
            }
            j
        })
        .collect();
    let mut out: Vec<[f64; 3]> = joint.clone();
    for k in 0..3 {
        let dir = held_directions(&joint, k);
        // Reversal moves: the full distance (rounded to steps for grblHAL) added on every
        // reversal in the new direction; starts as if the last move was negative.
        // grblHAL: lroundf(backlash × steps/mm) steps; Marlin: F × distance (backlash.cpp).
        let grbl = match s.reversal_steps_per_mm {
            Some(sp) => (s.grbl_backlash_mm[k] * sp).round() / sp,
            None => s.grbl_backlash_mm[k],
        };
        let rev = grbl + s.marlin_f * s.marlin_mm[k];
        for i in 0..out.len() {
            let mut corr = 0.0;
            match &s.comp[k] {
                Some(table) => corr += comp_trim(table, joint[i][k], dir[i]),
                None => corr += 0.5 * s.linuxcnc_backlash_mm[k] * dir[i],
            }
            if dir[i] > 0.0 {
                corr += rev;
            }
            out[i][k] = (joint[i][k] + corr) * s.travel_ratio[k] - ball_mm[k];
        }
    }
    let smooth = joint
        .iter()
        .map(|j| {
            let mut q = [0.0; 3];
            for k in 0..3 {
                q[k] = j[k] * s.travel_ratio[k] - ball_mm[k];
            }
            q
        })
        .collect();
    (out, smooth)
}

/// One machine and its test.
struct Case {
    name: &'static str,
    controller: Controller,
    radii_mm: Vec<f64>,
    plane: (usize, usize, usize),
    pitch_mm: [Option<f64>; 3],
    /// The machine's own errors (`simulate --effect` syntax).
    machine: Vec<&'static str>,
    /// Settings in force during the first test (`--current` file text), if any.
    current: Option<&'static str>,
    /// Effects the compensation must remove.
    compensated: Vec<&'static str>,
    /// Effects no setting can take, which must still be found.
    remaining: Vec<&'static str>,
    ball_mm: [f64; 3],
    comp_file_type: u8,
}

fn test_path(case: &Case) -> Path {
    let spec = PathSpec {
        radii_mm: case.radii_mm.clone(),
        heights_mm: vec![0.0],
        plane: case.plane,
        feed_mm_min: 1000.0,
        rate_hz: 250.0,
    };
    let (t, p) = nominal_path(&spec);
    Path::new(t, p, case.pitch_mm)
}

/// Run the test on the machine under `s`: D (mm) against the commanded path.
///
/// The machine's errors act at the motor positions; its direction of motion and speed are
/// those of the joint command (a correction move happens at the reversal, in the new direction,
/// within one sample). Deriving them from the sampled motor positions instead would see each
/// correction step as a reversal one sample early — an artifact of sampling, not physics.
fn measured(case: &Case, cmd: &Path, s: &Settings, machine: &[EffectValue], seed: u64) -> Vec<f64> {
    let (p, smooth) = motor_path(&cmd.p_mm, s, case.ball_mm);
    let smooth = Path::new(cmd.t_s.clone(), smooth, case.pitch_mm);
    let mut motor = Path::new(cmd.t_s.clone(), p, case.pitch_mm);
    motor.dir = smooth.dir.clone();
    motor.v_mm_s = smooth.v_mm_s.clone();
    let mut d = distances_mm(&motor, machine).unwrap();
    measure(&mut d, 0.3, 0.1, seed);
    d
}

/// Value ± σ of each effect of `set` fitted to `d` with the exact geometry.
fn forced_fit(path: &Path, d: &[f64], effects: &[Effect]) -> Vec<(Effect, f64, f64)> {
    let set = EffectSet::new(effects.to_vec());
    let model = ExactModel {
        path,
        d_mm: d,
        set: &set,
    };
    let fit = least_squares(&model, &vec![0.0; set.n_params], &LsqOptions::default()).unwrap();
    effects
        .iter()
        .zip(&set.offsets)
        .filter(|(e, _)| !e.is_setup())
        .map(|(e, &o)| {
            let n = e.n_params();
            let block: Vec<Vec<f64>> = (0..n)
                .map(|i| (0..n).map(|j| fit.covariance[(o + i, o + j)]).collect())
                .collect();
            let (v, s) = e.value(&fit.params[o..o + n], &block);
            (*e, v, s.unwrap_or(f64::NAN))
        })
        .collect()
}

fn doc_of(diag: &Diagnosis) -> DiagnosisDoc {
    let text = to_json(diag).to_string();
    DiagnosisDoc::parse(FsPath::new("diagnosis.json"), &text).unwrap()
}

fn found(diag: &Diagnosis, name: &str) -> Option<(f64, f64)> {
    diag.effects
        .iter()
        .find(|f| f.effect.name() == name)
        .map(|f| (f.value, f.sigma.unwrap_or(f64::NAN)))
}

/// The whole proof for one case; prints the before/after table.
fn prove(case: Case) -> Plan {
    let cmd = test_path(&case);
    let machine: Vec<EffectValue> = case
        .machine
        .iter()
        .map(|e| parse_effect(e).unwrap())
        .collect();
    let dir = tempfile::tempdir().unwrap();

    // Settings in force during the first test.
    let mut first = Settings::default();
    let mut steps0 = StepsPerMm::default();
    let current = match case.current {
        Some(text) => {
            let f = dir.path().join("current.txt");
            std::fs::write(&f, text).unwrap();
            let lines: Vec<String> = text.lines().map(|l| l.to_string()).collect();
            apply_text(case.controller, &lines, &[], &mut first, &mut steps0);
            Current::read(&f, case.controller).unwrap()
        }
        None => Current::none(),
    };
    let d1 = measured(&case, &cmd, &first, &machine, 11);
    let diag1 = diagnose(&cmd, &d1, &DiagOptions::default()).unwrap();
    let doc = doc_of(&diag1);
    let mut placement = Placement::default();
    for k in 0..3 {
        placement.table_ball_mm[k] = Some(case.ball_mm[k]);
    }
    let opts = Options {
        controller: case.controller,
        placement,
        comp_file_type: case.comp_file_type,
    };
    let p = plan(&doc, &current, &opts).unwrap();
    let text = jdbb::compensate::render(&p, None);

    // Apply what was emitted on top of the settings in force: each line sets what it names.
    let mut second = first.clone();
    let mut steps1 = steps0.clone();
    let lines: Vec<String> = p.blocks.iter().flat_map(|b| b.lines.clone()).collect();
    apply_text(case.controller, &lines, &p.files, &mut second, &mut steps1);
    for k in 0..3 {
        if let (Some(a), Some(b)) = (steps0.0[k], steps1.0[k]) {
            second.travel_ratio[k] = b / a;
        }
    }
    let d2 = measured(&case, &cmd, &second, &machine, 12);
    let diag2 = diagnose(&cmd, &d2, &DiagOptions::default()).unwrap();
    let effects1: Vec<Effect> = diag1.effects.iter().map(|f| f.effect).collect();
    let after = forced_fit(&cmd, &d2, &effects1);

    println!("== {} ({}):\n{text}", case.name, case.controller.name());
    println!(
        "{:<22} {:>24} {:>24} {:>8}",
        "effect", "before ± σ", "after ± σ (same model)", "|a|/σc"
    );
    let mut failures = vec![];
    for name in case.compensated.iter().chain(&case.remaining) {
        let (b, sb) = found(&diag1, name)
            .unwrap_or_else(|| panic!("{}: the first test must find {name}", case.name));
        let &(_, a, sa) = after
            .iter()
            .find(|(e, _, _)| e.name() == *name)
            .expect("fitted");
        let sc = sb.hypot(sa);
        println!(
            "{name:<22} {:>24} {:>24} {:>8.2}{}",
            format!("{b:.4} ± {sb:.4}"),
            format!("{a:.4} ± {sa:.4}"),
            a.abs() / sc,
            if case.compensated.contains(name) {
                ""
            } else {
                "  (not compensable: stays)"
            }
        );
        if case.compensated.contains(name) {
            if a.abs() >= 3.0 * sc {
                failures.push(format!("{name}: after {a} ± {sa} (σc {sc})"));
            }
            if let Some((v, s)) = found(&diag2, name) {
                if v.abs() >= 3.0 * s.hypot(sb) {
                    failures.push(format!("{name}: re-diagnosis selects it at {v} ± {s}"));
                }
            }
        } else if (a - b).abs() >= 3.0 * sc {
            failures.push(format!("{name} should stay: before {b}, after {a}"));
        }
    }
    let re: Vec<String> = diag2
        .effects
        .iter()
        .filter(|f| !f.effect.is_setup())
        .map(|f| {
            format!(
                "{} = {:.4} ± {:.4}",
                f.effect.name(),
                f.value,
                f.sigma.unwrap_or(f64::NAN)
            )
        })
        .collect();
    println!(
        "re-diagnosis selects: {}",
        if re.is_empty() {
            "nothing".into()
        } else {
            re.join(", ")
        }
    );
    assert!(failures.is_empty(), "{}: {failures:?}\n{text}", case.name);
    p
}

#[test]
fn linuxcnc_backlash_and_matrixkins_squareness() {
    let p = prove(Case {
        name: "LinuxCNC BACKLASH (with 3 µm in force on X) and matrixkins C_xy",
        controller: Controller::LinuxCnc,
        radii_mm: vec![90.0],
        plane: (0, 1, 2),
        pitch_mm: [None; 3],
        machine: vec![
            "backlash_x=8",
            "backlash_y=5",
            "squareness_xy=25",
            "servo_mismatch_xy=0.4",
            "setup_offset=12,-7,0",
        ],
        current: Some("[JOINT_0]\nBACKLASH = 0.003\n[JOINT_1]\nBACKLASH = 0.0\n"),
        compensated: vec!["backlash_x", "backlash_y", "squareness_xy"],
        remaining: vec!["servo_mismatch_xy"],
        ball_mm: [250.0, 120.0, -300.0],
        comp_file_type: 1,
    });
    // The new BACKLASH is the total: 3 µm in force + the 5 µm the test still saw.
    let b = p
        .changes
        .iter()
        .find(|c| c.setting == "[JOINT_0] BACKLASH")
        .unwrap();
    assert!((b.new - 0.008).abs() < 5e-5, "{b:?}");
}

#[test]
fn linuxcnc_comp_file_scale_cyclic_and_backlash() {
    // Three radii separate the isotropic scale (from the bar length and, at one feed, from the
    // loops' following error, −q·v²/R: two radii do not); the cyclic error at a 10 mm pitch
    // needs a table step of 1/16 pitch over the 140 mm tested; backlash moves into the table.
    let case = |t| Case {
        name: "LinuxCNC COMP_FILE (scale, cyclic, backlash in the table)",
        controller: Controller::LinuxCnc,
        radii_mm: vec![40.0, 55.0, 70.0],
        plane: (0, 1, 2),
        pitch_mm: [Some(10.0), None, None],
        machine: vec![
            "scale_x=30",
            "scale_y=-15",
            "cyclic_x=2@40",
            "backlash_x=6",
            "setup_offset=5,3,0",
        ],
        current: None,
        compensated: vec!["scale_x", "scale_y", "cyclic_x", "backlash_x"],
        remaining: vec![],
        ball_mm: [250.0, 120.0, -300.0],
        comp_file_type: t,
    };
    let p1 = prove(case(1));
    assert_eq!(p1.files.len(), 2, "x.comp and y.comp");
    // Type 0 writes the same trims as actual positions.
    let p0 = {
        let c = case(0);
        let machine: Vec<EffectValue> =
            c.machine.iter().map(|e| parse_effect(e).unwrap()).collect();
        let path = test_path(&c);
        let d = measured(&c, &path, &Settings::default(), &machine, 11);
        let diag = diagnose(&path, &d, &DiagOptions::default()).unwrap();
        let placement = Placement {
            table_ball_mm: [Some(250.0), Some(120.0), Some(-300.0)],
            ..Default::default()
        };
        plan(
            &doc_of(&diag),
            &Current::none(),
            &Options {
                controller: Controller::LinuxCnc,
                placement,
                comp_file_type: 0,
            },
        )
        .unwrap()
    };
    for ((n1, t1), (n0, t0)) in p1.files.iter().zip(&p0.files) {
        assert_eq!(n1, n0);
        for (l1, l0) in t1.lines().zip(t0.lines()) {
            let a: Vec<f64> = l1.split_whitespace().map(|x| x.parse().unwrap()).collect();
            let b: Vec<f64> = l0.split_whitespace().map(|x| x.parse().unwrap()).collect();
            assert_eq!(a[0], b[0]);
            assert!((a[1] - (b[0] - b[1])).abs() < 2e-7 && (a[2] - (b[0] - b[2])).abs() < 2e-7);
        }
    }
}

#[test]
fn grblhal_backlash() {
    prove(Case {
        name: "grblHAL $160/$161",
        controller: Controller::GrblHal,
        radii_mm: vec![90.0],
        plane: (0, 1, 2),
        pitch_mm: [None; 3],
        machine: vec!["backlash_x=8", "backlash_y=5", "squareness_xy=20"],
        current: None,
        compensated: vec!["backlash_x", "backlash_y"],
        remaining: vec!["squareness_xy"],
        ball_mm: [0.0; 3],
        comp_file_type: 1,
    });
}

#[test]
fn grblhal_backlash_in_whole_steps_leaves_at_most_half_a_step() {
    // grblHAL rounds the backlash move to whole steps (lroundf(backlash × steps/mm)); with
    // 400 steps/mm (2.5 µm) the remaining lost motion is at most half a step.
    let c = Case {
        name: "grblHAL, steps",
        controller: Controller::GrblHal,
        radii_mm: vec![90.0],
        plane: (0, 1, 2),
        pitch_mm: [None; 3],
        machine: vec!["backlash_x=8", "backlash_y=5"],
        current: None,
        compensated: vec![],
        remaining: vec![],
        ball_mm: [0.0; 3],
        comp_file_type: 1,
    };
    let cmd = test_path(&c);
    let machine: Vec<EffectValue> = c.machine.iter().map(|e| parse_effect(e).unwrap()).collect();
    let diag = diagnose(
        &cmd,
        &measured(&c, &cmd, &Settings::default(), &machine, 11),
        &DiagOptions::default(),
    )
    .unwrap();
    let opts = Options {
        controller: Controller::GrblHal,
        placement: Placement::default(),
        comp_file_type: 1,
    };
    let p = plan(&doc_of(&diag), &Current::none(), &opts).unwrap();
    let mut s = Settings {
        reversal_steps_per_mm: Some(400.0),
        ..Default::default()
    };
    let lines: Vec<String> = p.blocks.iter().flat_map(|b| b.lines.clone()).collect();
    apply_text(
        c.controller,
        &lines,
        &[],
        &mut s,
        &mut StepsPerMm::default(),
    );
    let d = measured(&c, &cmd, &s, &machine, 12);
    let after = forced_fit(
        &cmd,
        &d,
        &diag.effects.iter().map(|f| f.effect).collect::<Vec<_>>(),
    );
    for (e, v, sigma) in after {
        println!("{e}: {v:.4} ± {sigma:.4} µm (half a step: 1.25 µm)");
        assert!(v.abs() <= 1.25 + 3.0 * sigma, "{e} {v}");
    }
}

#[test]
fn marlin_backlash_skew_and_steps_with_values_in_force() {
    // In force during the test: 2 µm of X backlash at F0.5 (1 µm effective), a skew factor, and
    // steps/mm; the emitted values must be the new totals.
    prove(Case {
        name: "Marlin M425 + M852 I + M92 (values in force)",
        controller: Controller::Marlin,
        radii_mm: vec![90.0],
        plane: (0, 1, 2),
        pitch_mm: [None; 3],
        machine: vec![
            "backlash_x=8",
            "backlash_y=5",
            "squareness_xy=25",
            "scale_mismatch_xy=40",
            "setup_offset=-9,4,0",
        ],
        current: Some(
            "echo:  M92 X80.00 Y80.00 Z400.00 E93.00\necho:  M425 F0.5 S0.00 X0.002 Y0.00 Z0.00\nM852 I0.00001\n",
        ),
        compensated: vec!["backlash_x", "backlash_y", "squareness_xy", "scale_mismatch_xy"],
        remaining: vec![],
        ball_mm: [100.0, 100.0, 0.0],
        comp_file_type: 1,
    });
}

#[test]
fn marlin_zx_plane_skew_factor_j() {
    // squareness_zx (δ_z = s·x) is Marlin's XZ factor J = s (a rotation about y apart).
    prove(Case {
        name: "Marlin M852 J in the zx plane, M425 Z and X",
        controller: Controller::Marlin,
        radii_mm: vec![80.0],
        plane: (2, 0, 1),
        pitch_mm: [None; 3],
        machine: vec!["squareness_zx=30", "backlash_z=6", "backlash_x=4"],
        current: None,
        compensated: vec!["squareness_zx", "backlash_z", "backlash_x"],
        remaining: vec![],
        ball_mm: [0.0; 3],
        comp_file_type: 1,
    });
}

#[test]
fn klipper_skew_xy_and_rotation_distance() {
    prove(Case {
        name: "Klipper SET_SKEW XY + rotation_distance (values in force)",
        controller: Controller::Klipper,
        radii_mm: vec![60.0, 80.0, 100.0],
        plane: (0, 1, 2),
        pitch_mm: [None; 3],
        machine: vec!["squareness_xy=-35", "scale_x=50", "scale_y=20", "backlash_x=5"],
        current: Some(
            "[stepper_x]\nrotation_distance: 40\n[stepper_y]\nrotation_distance: 40\n#*# [skew_correction jdbb]\n#*# xy_skew = -0.00001\n",
        ),
        compensated: vec!["squareness_xy", "scale_x", "scale_y"],
        remaining: vec!["backlash_x"],
        ball_mm: [150.0, 150.0, 0.0],
        comp_file_type: 1,
    });
}

#[test]
fn klipper_skew_yz() {
    prove(Case {
        name: "Klipper SET_SKEW YZ",
        controller: Controller::Klipper,
        radii_mm: vec![80.0],
        plane: (1, 2, 0),
        pitch_mm: [None; 3],
        machine: vec!["squareness_yz=-20"],
        current: None,
        compensated: vec!["squareness_yz"],
        remaining: vec![],
        ball_mm: [0.0; 3],
        comp_file_type: 1,
    });
}
