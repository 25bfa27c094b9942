//! The printout of `jdbb plan --volumetric` ([`crate::volumetric`]): where to put the table ball
//! and mount the instrument, the elements, the travel and range used, the run time, and what
//! the test determines of the machine's linear errors.
use std::path::Path;

use super::plan::{place_text, reach_text, written_text};
use crate::plan::{gcode, Dialect, Plan};
use crate::volumetric::ident::{combination_text, identifiability, separation_text, Term};
use crate::volumetric::plan::{data_points_mm, element_kind};

/// Degrees as the printout writes them: to the millidegree, without trailing zeros.
fn deg(x: f64) -> String {
    gcode::number(x)
        .trim_end_matches('0')
        .trim_end_matches('.')
        .to_string()
}

/// What the operator needs for a volumetric plan, and what it determines.
pub fn setup_text(plan: &Plan, json: &Path, program: &Path, blocks: usize) -> String {
    let mut t = format!(
        "volumetric test from one table ball: {} element(s), each ccw then cw at {} mm/min ({})\n",
        plan.circles.len(),
        gcode::number(plan.feed_mm_min),
        plan.dialect.name()
    );
    t += &place_text(plan, "; it stays mounted to the end");
    t += "elements, in program order (moves between them run along the shell, over the ball):\n";
    for (k, c) in plan.circles.iter().enumerate() {
        let arc = c.arc.unwrap_or(plan.arc);
        let (i, _, _) = c.plane.axes();
        let run = if arc.is_partial() {
            format!(
                "{}° from {}° of {} (data {}°)",
                deg(arc.sweep_deg),
                deg(arc.start_deg),
                ["x", "y", "z"][i],
                deg(arc.data_sweep_deg)
            )
        } else {
            "full circle".to_string()
        };
        t += &format!(
            "  {:>2}  {:<10}R {:>8.3} mm  H {:>8.3} mm  D {:>8.3} mm  {run}\n",
            k + 1,
            element_kind(plan, k),
            c.radius_mm,
            c.height_mm,
            c.d_mm
        );
    }
    t += &reach_text(plan, "elements");
    let (lo, _) = plan.travel_mm();
    let below_mm = plan.centre_mm[2] - lo[2];
    if below_mm > 1e-3 {
        t += &format!(
            "note: the arcs pass {below_mm:.3} mm below the table ball's centre (Z {:.3}): the table ball must stand that high above the table, plus the spindle ball's holder\n",
            lo[2]
        );
    }
    if plan.dialect == Dialect::Marlin {
        t += "note: Marlin selects G18/G19 only with CNC_WORKSPACE_PLANES; without it the zx and yz arcs run in XY\n";
    }
    t += &identifiability_text(plan);
    t + &written_text(plan, json, program, blocks)
}

/// The identifiability table of a plan's data arcs ([`crate::volumetric::ident`]).
fn identifiability_text(plan: &Plan) -> String {
    let id = identifiability(&data_points_mm(plan));
    let names = |want: bool| {
        id.determined
            .iter()
            .filter(|(_, d)| *d == want)
            .map(|(t, _)| t.name())
            .collect::<Vec<_>>()
            .join(", ")
    };
    let mut t = format!(
        "what it determines of the machine's linear errors (3 scales, 3 squarenesses, the table ball's set-up offset; the instrument's calibration L1 + L2 as the length reference), from {} points of the data arcs:\n",
        id.rows
    );
    let determined = names(true);
    t += &format!(
        "  determined:        {}\n",
        if determined.is_empty() {
            "nothing".into()
        } else {
            determined
        }
    );
    let not = names(false);
    if !not.is_empty() {
        t += &format!("  not determined:    {not}\n");
    }
    t += &format!(
        "  rank:              {} of {} with the calibration ({} of {} without: the instrument's scale is a term too)\n",
        id.rank_with_reference,
        Term::ALL.len() - 1,
        id.rank,
        Term::ALL.len()
    );
    t += &format!(
        "  condition number:  {:.1} (columns scaled to unit norm)\n",
        id.condition
    );
    for v in &id.confounded {
        t += &format!(
            "  confounded:        {}: separated by {}\n",
            combination_text(v),
            separation_text(v)
        );
    }
    t += "  not from one mount: angular errors (pitch, yaw, roll) through the fixed lever arm read as these scales and squarenesses; a second lever arm (another stem length or table ball position) separates them\n";
    t
}
