//! Heidenhain iTNC 530 (machine parameters MPxxx) and TNC 640 (configuration data): backlash,
//! reversal-spike compensation, linear axis error compensation and nonlinear axis error
//! compensation tables (`*.COM`, assigned in a `*.CMA`), in mm.
//!
//! Semantics (sources in `docs/controllers.md`; TNC 407/415/425 and TNC 426/430 technical
//! manuals, iTNC 530 HSCI technical manual, MANUALplus 620 technical manual):
//! - **MP710.x** backlash, −1…+1 mm: "positive backlash: the rotary encoder reading is ahead of the
//!   table, the table traverse is too short", entered as the value the TNC adds at each reversal:
//!   **B = b**. With a linear encoder closing the loop the play is inside it: MP750.x (reversal
//!   error, mm) with MP752.x (ms) instead. TNC 640: `MP_backLash` of the axis (named so in the
//!   MANUALplus 620 manual of the same generation; **not confirmed** from a TNC 640 manual).
//! - **MP711.x / MP712.x** reversal spikes (TNC 426/430 §6.4.5): MP712 = spike [µm] × control loop
//!   cycle time [s] × 10⁻³ / (0.5 × t_SpD [s]), t_SpD the spike's duration; for the exponential
//!   spike the diagnosis fits (height h, time constant τ) the triangle of the same area has
//!   0.5·t_SpD = τ. The cycle time is the control's (3 ms **assumed** here, said); MP711 is taken as
//!   the peak height (mm), **not confirmed**. No TNC 640 equivalent was found.
//! - **MP720.x** linear axis error, −1…+1 mm/m: "positive if the table travel is too long", i.e.
//!   the scale error itself (δ = a·x: MP720 = a/1000). MP730 bit x: 0 linear, 1 nonlinear (one or
//!   the other per axis).
//! - **Nonlinear** (`*.COM`, at most 256 points): `AXISPOS` the compensation points from the
//!   machine datum, a column per compensated axis holding its error as a function of the axis of
//!   the `AXISPOS` column ("[axis in column of *.com] = F(axis of the *.cma column it is entered
//!   in)"), so squareness δ_x = s·y is an X column in the table over Y. The values are entered as
//!   the error with MP720's sign rule (**the sign of a COM value is taken from MP720's rule, not
//!   confirmed** from the nonlinear section's text), linear between points (assumed). The `*.CMA`
//!   (standard name config.cma) assigns the tables, one line marked active with `*`.
//!
//! # `--current` format
//! iTNC 530 machine-parameter lines as the MP file has them, `MP710.0:+0.0120` (or `=`); MP710,
//! MP720 are read, x = 0, 1, 2 for X, Y, Z; other lines ignored.
use std::fmt::Write;
use std::path::Path;

use super::current::{key_value, number, Current};
use super::{
    change, defaults_note, linear_table, table_change, table_span_mm, Block, MachineErrors,
    Placement, Plan,
};
use crate::model::{Axis, Pair};
use crate::Result;

/// Most points of one `*.COM` table.
pub const MAX_COM_POINTS: usize = 256;
/// The control loop cycle time assumed for MP712 (s).
pub const ASSUMED_CYCLE_S: f64 = 0.003;

/// Read the `--current` format (module docs).
pub fn parse_current(path: &Path, text: &str) -> Result<Current> {
    let mut c = Current::none();
    for (n, line) in text.lines().enumerate() {
        let Some((key, value, col)) = key_value(line) else {
            continue;
        };
        let key = key.to_ascii_uppercase();
        if ["MP710.", "MP720.", "MP750."]
            .iter()
            .any(|p| key.starts_with(p))
        {
            let v = number(path, n + 1, col, &value, &key)?;
            c.set(key, v);
        }
    }
    Ok(c)
}

/// The column name of `a` in a table.
fn col(a: Axis) -> char {
    a.letter().to_ascii_uppercase()
}

/// What to change on a Heidenhain TNC (module docs).
pub fn plan(m: &MachineErrors, current: &Current, placement: &Placement) -> Result<Plan> {
    let mut p = Plan {
        title: "Heidenhain iTNC 530 (MP, axes X=0 Y=1 Z=2) / TNC 640, mm".into(),
        ..Default::default()
    };
    p.notes.extend(defaults_note(current));
    let mut mp = vec![];
    // An axis compensated through a COM table: its own error beyond a scale, or the output of a
    // squareness.
    let nonlinear = |a: Axis| {
        m.scale2_um_per_m2[a.index()].is_some()
            || m.cyclic[a.index()].is_some()
            || Pair::ALL
                .iter()
                .any(|&q| m.squareness(q).is_some() && q.axes().0 == a)
    };
    for a in Axis::ALL {
        let k = a.index();
        if let Some(b) = &m.backlash_um[k] {
            let c = change(
                b.text(),
                format!("MP710.{k} (TNC 640: MP_backLash of {})", col(a)),
                "mm",
                current.get(&format!("MP710.{k}")),
                0.0,
                1e-3 * b.value,
                4,
            );
            mp.push(format!("MP710.{k}:{:+.4}", c.new));
            p.changes.push(c);
        }
        if let Some((h_um, tau_ms)) = m.reversal_spike[k] {
            if tau_ms > 0.0 {
                let per_cycle_mm = 1e-3 * h_um * ASSUMED_CYCLE_S / (1e-3 * tau_ms);
                mp.push(format!("MP711.{k}:{:+.4}", 1e-3 * h_um));
                mp.push(format!("MP712.{k}:{:+.6}", per_cycle_mm));
                p.notes.push(format!(
                    "{}: reversal-spike compensation (iTNC 530) from a spike of {h_um:.2} µm decaying in {tau_ms:.2} ms: MP712 = h·T·10⁻³/(0.5·t_SpD) with 0.5·t_SpD = τ and a control loop cycle time T of 3 ms ASSUMED (scale MP712 by your control's T / 3 ms); MP711 as the peak height is not confirmed. TNC 640: no reversal-spike parameter confirmed, use its friction compensation with the builder",
                    col(a)
                ));
            }
        }
        if m.scale_um_per_m[k].is_some() && !nonlinear(a) {
            let (s, src) = m.scale_um_per_m[k].as_ref().unwrap();
            let c = change(
                src.text(),
                format!("MP720.{k} (linear axis error)"),
                "mm/m",
                current.get(&format!("MP720.{k}")),
                0.0,
                1e-3 * s,
                4,
            );
            mp.push(format!("MP720.{k}:{:+.4}", c.new));
            p.changes.push(c);
        }
    }
    // One COM table per axis of the AXISPOS column.
    let mut cma: Vec<(Axis, String)> = vec![];
    for j in Axis::ALL {
        let own = nonlinear(j) && m.position_dependent(j);
        let leaning: Vec<(Axis, &super::Measured)> = Pair::ALL
            .iter()
            .filter_map(|&q| {
                let (i, jj) = q.axes();
                (jj == j).then_some(())?;
                m.squareness(q).map(|s| (i, s))
            })
            .collect();
        if !own && leaning.is_empty() {
            continue;
        }
        let span = table_span_mm(m, j, placement, None)?;
        // A squareness alone is a straight line: its two ends.
        let points = if own { MAX_COM_POINTS } else { 2 };
        let table = linear_table(m, j, placement, span, points, 0.0);
        let name = format!("{}.COM", col(j));
        let mut columns = vec![];
        if own {
            columns.push(col(j));
        }
        columns.extend(leaning.iter().map(|(i, _)| col(*i)));
        let mut text = format!("BEGIN {name} MM\nNR    AXISPOS    ");
        for c in &columns {
            let _ = write!(text, "{c:<10} ");
        }
        text.push_str("BACKLASH\n");
        for (n, (x, e)) in table.iter().enumerate() {
            let _ = write!(text, "{n:<5} {x:<+10.4} ");
            if own {
                let _ = write!(text, "{e:<+10.5} ");
            }
            for (_, s) in &leaning {
                let _ = write!(text, "{:<+10.5} ", 1e-6 * s.value * x);
            }
            text.push_str("+0.0000\n");
        }
        text.push_str("[END]\n");
        let mut because = vec![];
        if own {
            because.extend(m.position_sources(j));
        }
        because.extend(leaning.iter().map(|(_, s)| s.text()));
        p.changes.push(table_change(
            because.join(", "),
            format!("nonlinear axis error compensation {name}"),
            false,
            format!(
                "{} points every {:.4} mm of {}, columns {} = F({})",
                table.len(),
                table[1].0 - table[0].0,
                col(j),
                columns
                    .iter()
                    .map(char::to_string)
                    .collect::<Vec<_>>()
                    .join(", "),
                col(j)
            ),
        ));
        p.files.push((name.clone(), text));
        cma.push((j, name));
    }
    if !cma.is_empty() {
        let mut text =
            "BEGIN CONFIG.CMA\nNR    ACTIVE  X          Y          Z\n0     *       ".to_string();
        for a in Axis::ALL {
            let cell = cma
                .iter()
                .find(|(j, _)| *j == a)
                .map_or(String::new(), |(_, n)| n.clone());
            let _ = write!(text, "{cell:<10} ");
        }
        text = text.trim_end().to_string() + "\n[END]\n";
        p.files.push(("CONFIG.CMA".into(), text));
        let bits: String = Axis::ALL
            .iter()
            .rev()
            .map(|&a| if nonlinear(a) { '1' } else { '0' })
            .collect();
        mp.push(format!("MP730:%{bits}"));
        p.notes.push("the *.COM tables and CONFIG.CMA: values are each axis' error (mm) as a function of the AXISPOS axis, from the machine datum, with MP720's sign rule (not confirmed for COM values: a wrong sign doubles the error on the next test); the column layout is the table editor's as far as the technical manuals show it — enter through the table editor if an import refuses. Nonlinear compensation is selected per axis by MP730 (iTNC 530); on the TNC 640 the tables are assigned in the same way through its configuration".into());
    }
    if !mp.is_empty() {
        p.blocks.push(Block {
            label:
                "the machine parameters (code number 95148; active when the parameter list is left)"
                    .into(),
            lines: mp,
        });
    }
    Ok(p)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn machine_parameter_lines_are_read_and_bad_values_located() {
        let c = parse_current(
            Path::new("mp.txt"),
            "MP710.0:+0.0120\nMP720.1 = -0.010\nMP10:1\n",
        )
        .unwrap();
        assert_eq!(c.get("MP710.0"), Some(0.012));
        assert_eq!(c.get("MP720.1"), Some(-0.010));
        let e = parse_current(Path::new("mp.txt"), "MP710.1:+0.0l2\n").unwrap_err();
        assert!(e.to_string().contains("mp.txt:1:9: MP710.1"), "{e}");
    }
}
