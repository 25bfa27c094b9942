//! Siemens SINUMERIK 840D sl / ONE: backlash (MD32450), leadscrew error compensation (LEC/EEC,
//! `$AA_ENC_COMP` tables enabled by MD32700) as a part program, squareness through sag/angularity
//! compensation (`$AN_CEC` tables, MD32710).
//!
//! Semantics (sources in `docs/controllers.md`; Function Manual Extended Functions K3
//! 6FC5397-1BP20/1BP40, SINUMERIK 808D parameter and function manuals, 840C NC MD 220*):
//! - **MD32450 `$MA_BACKLASH[0,AXn]`** (mm, NEW CONF): "positive, if the encoder is leading the
//!   machine part (normal situation)", i.e. positive for play; the whole value is applied at each
//!   reversal, active after reference point approach, so **B = b**.
//! - **`$AA_ENC_COMP[0,N,AXn]`**: compensation value of point N (mm), points `$AA_ENC_COMP_STEP`
//!   apart from `$AA_ENC_COMP_MIN` to `$AA_ENC_COMP_MAX`, linear between points, the first and
//!   last values held beyond the table; "a positive compensation value causes the corresponding
//!   machine axis to move in the negative direction", so the value is **+δ** (the error itself).
//!   The value at the reference point should be zero (no jump when it becomes active): the table
//!   here is zero at the reference point (`$MA_REFP_SET_POS[0,AXn]` in `--current`, else machine
//!   0, said). MD38000 `MM_ENC_COMP_MAX_POINTS` must hold the points (a memory setting: POWER ON);
//!   the table is loaded with MD32700 ENC_COMP_ENABLE = 0, then MD32700 = 1 and NEWCONFIG (or a
//!   power cycle); it acts once the axis is referenced.
//! - Squareness: a CEC table (`$AN_CEC[t,N]`, input axis `$AN_CEC_INPUT_AXIS[t]`, output axis
//!   `$AN_CEC_OUTPUT_AXIS[t]`, `$AN_CEC_STEP/MIN/MAX[t]`, enabled by `$SN_CEC_TABLE_ENABLE[t]`,
//!   MD32710 CEC_ENABLE of the output axis, memory MD18342 MM_CEC_MAX_POINTS[t]). **Not
//!   confirmed:** the sign of a CEC value; jdbb writes it as for `$AA_ENC_COMP` (the error) and
//!   says so.
//! - Units: mm, or inch where `$MN_SCALING_SYSTEM_IS_METRIC = 0` in `--current` (then the values
//!   are in inch).
//!
//! Machine axes AX1, AX2, AX3 are X, Y, Z (use the names of MD10000 if they differ).
//!
//! # `--current` format
//! Machine-data archive or `.INI` lines `$MA_BACKLASH[0,AX1]=0.012`,
//! `$MN_SCALING_SYSTEM_IS_METRIC=1`, `$MA_REFP_SET_POS[0,AX1]=0`, and a table in force as
//! `$AA_ENC_COMP[0,N,AX1]=…` with its `_STEP`, `_MIN` lines (axis as AXn, Xn or the letter);
//! other lines are ignored.
use std::path::Path;

use super::current::{number, Current};
use super::{
    change, defaults_note, linear_table, table_at, table_change, table_span_mm, Block,
    MachineErrors, Placement, Plan,
};
use crate::model::{Axis, Pair};
use crate::{Error, Result};

/// Most points jdbb writes in one axis' EEC table.
pub const MAX_EEC_POINTS: usize = 1025;

/// The machine axis name of `a`.
fn ax(a: Axis) -> String {
    format!("AX{}", a.index() + 1)
}

/// The axis an index names: AX1, X1 or X for X.
fn axis_of(token: &str) -> Option<Axis> {
    let t = token.trim().to_ascii_uppercase();
    match t.as_str() {
        "AX1" | "X1" | "X" => Some(Axis::X),
        "AX2" | "Y1" | "Y" => Some(Axis::Y),
        "AX3" | "Z1" | "Z" => Some(Axis::Z),
        _ => None,
    }
}

/// Read the `--current` format (module docs).
pub fn parse_current(path: &Path, text: &str) -> Result<Current> {
    let mut c = Current::none();
    for (n, line) in text.lines().enumerate() {
        let body = line.split(';').next().unwrap_or("");
        let t = body.trim_start();
        if !t.starts_with('$') {
            continue;
        }
        let Some(eq) = body.find('=') else { continue };
        let lhs = body[..eq].trim();
        let value = body[eq + 1..].trim();
        let col = eq + 2 + (body[eq + 1..].len() - body[eq + 1..].trim_start().len());
        let (name, idx) = match lhs.find('[') {
            Some(i) => (
                &lhs[..i],
                lhs[i + 1..]
                    .trim_end_matches(']')
                    .split(',')
                    .map(str::trim)
                    .collect::<Vec<_>>(),
            ),
            None => (lhs, vec![]),
        };
        let axis = idx.last().and_then(|t| axis_of(t));
        let key = match (name.to_ascii_uppercase().as_str(), axis, &idx[..]) {
            ("$MN_SCALING_SYSTEM_IS_METRIC", _, _) => "METRIC".to_string(),
            ("$MA_BACKLASH", Some(a), _) => format!("BACKLASH.{}", a.letter()),
            ("$MA_REFP_SET_POS", Some(a), _) => format!("REFP.{}", a.letter()),
            ("$AA_ENC_COMP", Some(a), [_, point, _]) => {
                let point: usize = point.parse().map_err(|_| {
                    Error::input(
                        path,
                        n + 1,
                        body.find('[').map_or(1, |i| i + 2),
                        format!("{lhs}: the point number `{point}` is not a whole number"),
                    )
                })?;
                format!("EEC.{}.{point}", a.letter())
            }
            ("$AA_ENC_COMP_STEP", Some(a), _) => format!("EEC_STEP.{}", a.letter()),
            ("$AA_ENC_COMP_MIN", Some(a), _) => format!("EEC_MIN.{}", a.letter()),
            _ => continue,
        };
        let v = number(path, n + 1, col, value, lhs)?;
        c.set(key, v);
    }
    Ok(c)
}

/// The table in force for `a`: (min, step, values) in machine units.
fn table_in_force(current: &Current, a: Axis) -> Option<(f64, f64, Vec<f64>)> {
    let l = a.letter();
    let step = current.get(&format!("EEC_STEP.{l}"))?;
    let min = current.get(&format!("EEC_MIN.{l}"))?;
    let values: Vec<f64> = (0..)
        .map_while(|n| current.get(&format!("EEC.{l}.{n}")))
        .collect();
    (!values.is_empty() && step > 0.0).then_some((min, step, values))
}

/// What to change on a SINUMERIK (module docs).
pub fn plan(m: &MachineErrors, current: &Current, placement: &Placement) -> Result<Plan> {
    let inch = current.get("METRIC") == Some(0.0);
    let (unit, u, decimals) = if inch {
        ("inch", 25.4, 7)
    } else {
        ("mm", 1.0, 6)
    };
    let mut p = Plan {
        title: format!(
            "SINUMERIK 840D sl / ONE, machine axes X=AX1 Y=AX2 Z=AX3, {unit}{}",
            if current.get("METRIC").is_none() {
                " (assumed: give $MN_SCALING_SYSTEM_IS_METRIC in --current)"
            } else {
                ""
            }
        ),
        ..Default::default()
    };
    p.notes.extend(defaults_note(current));
    let mut md = vec![];
    let mut program = vec!["%_N_AX_EEC_INI".to_string(), "CHANDATA(1)".to_string()];
    let mut enable = vec![];
    for a in Axis::ALL {
        let l = a.letter();
        if let Some(b) = &m.backlash_um[a.index()] {
            let c = change(
                b.text(),
                format!("MD32450 $MA_BACKLASH[0,{}]", ax(a)),
                unit,
                current.get(&format!("BACKLASH.{l}")),
                0.0,
                1e-3 * b.value / u,
                decimals,
            );
            md.push(format!(
                "$MA_BACKLASH[0,{}]={:.d$}",
                ax(a),
                c.new,
                d = decimals
            ));
            p.changes.push(c);
        }
        if !m.position_dependent(a) {
            continue;
        }
        let reference = current.get(&format!("REFP.{l}")).map_or(0.0, |r| r * u);
        if current.get(&format!("REFP.{l}")).is_none() {
            p.notes.push(format!(
                "{}: the table is zero at machine 0, taken as the reference point (give $MA_REFP_SET_POS[0,{}] in --current if it is elsewhere)",
                l.to_ascii_uppercase(),
                ax(a)
            ));
        }
        let span = table_span_mm(m, a, placement, None)?;
        let table = linear_table(m, a, placement, span, MAX_EEC_POINTS, reference);
        let old = table_in_force(current, a);
        let step_mm = table[1].0 - table[0].0;
        for (i, (x, e)) in table.iter().enumerate() {
            let before = old
                .as_ref()
                .map_or(0.0, |(min, step, v)| table_at(*min, *step, v, x / u));
            program.push(format!(
                "$AA_ENC_COMP[0,{i},{}]={:.d$}",
                ax(a),
                before + e / u,
                d = decimals
            ));
        }
        program.push(format!(
            "$AA_ENC_COMP_STEP[0,{}]={:.d$}",
            ax(a),
            step_mm / u,
            d = decimals
        ));
        program.push(format!(
            "$AA_ENC_COMP_MIN[0,{}]={:.d$}",
            ax(a),
            span.0 / u,
            d = decimals
        ));
        program.push(format!(
            "$AA_ENC_COMP_MAX[0,{}]={:.d$}",
            ax(a),
            span.1 / u,
            d = decimals
        ));
        program.push(format!("$AA_ENC_COMP_IS_MODULO[0,{}]=0", ax(a)));
        enable.push(format!("$MA_ENC_COMP_ENABLE[0,{}]=1", ax(a)));
        let because = m.position_sources(a);
        p.changes.push(table_change(
            because.join(", "),
            format!("leadscrew error compensation {}", ax(a)),
            old.is_some(),
            format!(
                "{} points every {:.4} mm from {:.3} mm in AX_EEC_INI.SPF{} (MD38000 $MA_MM_ENC_COMP_MAX_POINTS[0,{}] ≥ {})",
                table.len(),
                step_mm,
                span.0,
                if old.is_some() { ", the table in force added to" } else { "" },
                ax(a),
                table.len()
            ),
        ));
    }
    // Squareness: one CEC table per leaning pair, two points over the span of the input axis.
    let mut cec = vec![];
    let mut t = 0;
    for pair in Pair::ALL {
        let Some(s) = m.squareness(pair) else {
            continue;
        };
        let (i, j) = pair.axes();
        let (lo, hi) = table_span_mm(m, j, placement, None)?;
        let k0 = placement.table_ball_mm[j.index()].unwrap_or(0.0);
        // δ_i = s·(j − ball), zero at the table ball (a CEC table shifts i by its value).
        let e = |y: f64| 1e-9 * s.value * (y - k0) * 1e3 / u;
        cec.push(format!("$AN_CEC[{t},0]={:.d$}", e(lo), d = decimals));
        cec.push(format!("$AN_CEC[{t},1]={:.d$}", e(hi), d = decimals));
        cec.push(format!("$AN_CEC_INPUT_AXIS[{t}]={}", ax(j)));
        cec.push(format!("$AN_CEC_OUTPUT_AXIS[{t}]={}", ax(i)));
        cec.push(format!(
            "$AN_CEC_STEP[{t}]={:.d$}",
            (hi - lo) / u,
            d = decimals
        ));
        cec.push(format!("$AN_CEC_MIN[{t}]={:.d$}", lo / u, d = decimals));
        cec.push(format!("$AN_CEC_MAX[{t}]={:.d$}", hi / u, d = decimals));
        cec.push(format!("$SN_CEC_TABLE_ENABLE[{t}]=TRUE"));
        enable.push(format!("$MA_CEC_ENABLE[{}]=1", ax(i)));
        p.changes.push(table_change(
            s.text(),
            format!("sag/angularity compensation table {t}"),
            false,
            format!(
                "{} = f({}) in AX_EEC_INI.SPF (MD18342 $MN_MM_CEC_MAX_POINTS[{t}] ≥ 2)",
                ax(i),
                ax(j)
            ),
        ));
        t += 1;
    }
    if !cec.is_empty() {
        program.extend(cec);
        p.notes.push("squareness through a CEC (sag/angularity) table: the sign of $AN_CEC values is taken as for $AA_ENC_COMP (the error; the control moves the output axis against it) — NOT CONFIRMED from a source: check the first test after entering it, a wrong sign doubles the squareness. CEC may be an option the machine builder has not enabled; without it, square the axes mechanically".into());
    }
    if !md.is_empty() {
        p.blocks.push(Block {
            label: "the machine data (then NEWCONFIG or a reset; active after reference point approach)".into(),
            lines: md,
        });
    }
    if program.len() > 2 {
        program.push("M17".into());
        p.files
            .push(("AX_EEC_INI.SPF".into(), program.join("\n") + "\n"));
        enable.sort();
        enable.dedup();
        p.blocks.push(Block {
            label: "the machine data after running AX_EEC_INI.SPF with them at 0 (MD38000/MD18342 first: memory settings, POWER ON; then these and NEWCONFIG; active once the axes are referenced)".into(),
            lines: enable,
        });
    }
    Ok(p)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn machine_data_lines_are_read_and_bad_values_located() {
        let c = parse_current(
            Path::new("md.ini"),
            "; archive\n$MN_SCALING_SYSTEM_IS_METRIC=0\n$MA_BACKLASH[0,AX2]=0.0004\n$AA_ENC_COMP[0,1,X1]=0.0001\n$AA_ENC_COMP_STEP[0,AX1]=2\n",
        )
        .unwrap();
        assert_eq!(c.get("METRIC"), Some(0.0));
        assert_eq!(c.get("BACKLASH.y"), Some(0.0004));
        assert_eq!(c.get("EEC.x.1"), Some(0.0001));
        let e = parse_current(Path::new("md.ini"), "\n$MA_BACKLASH[0,AX1]=0.0o1\n").unwrap_err();
        assert!(e.to_string().contains("md.ini:2:21: $MA_BACKLASH"), "{e}");
        assert_eq!(e.exit_code(), 2);
    }
}
