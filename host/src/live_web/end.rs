//! The end-of-test diagnosis of `jdbb record --plan --web`: the finished record synchronised
//! with its plan and diagnosed exactly as `jdbb diagnose --record FILE --plan plan.json` does
//! (same functions, default options, no pitch), as the text that command prints.
use std::path::Path;

use super::state::Verdict;
use crate::diagnose::planned::diagnose_record as diagnose_planned_record;
use crate::diagnose::Options;
use crate::plan::Plan;
use crate::report::{summary, sync_summary, tolerance_verdict};
use crate::sync::Record;
use crate::Result;

/// Synchronise and diagnose the record at `record` with `plan`; the text `jdbb diagnose --record
/// --plan [--tolerance-um]` prints (synchronisation, diagnosis, verdict), and the verdict when a
/// tolerance is given.
pub fn diagnose_record(
    plan: &Plan,
    record: &Path,
    tolerance_um: Option<f64>,
) -> Result<(String, Option<Verdict>)> {
    let rec = Record::read(record)?;
    let done = diagnose_planned_record(plan, &rec, [None; 3], &Options::default())?;
    let diag = done.diagnosis;
    // As `jdbb diagnose` prints them: the two summaries as they are, the verdict as a line.
    let mut text = sync_summary(plan, &done.sync);
    if let Some(note) = rec.set_aside_note(Some(&done.sync)) {
        text.push_str(&note);
        text.push('\n');
    }
    text.push_str(&summary(&diag));
    let verdict = tolerance_um.map(|tol| {
        let (pass, line) = tolerance_verdict(&diag, tol);
        text.push_str(&line);
        text.push('\n');
        Verdict { pass, text: line }
    });
    Ok((text, verdict))
}
