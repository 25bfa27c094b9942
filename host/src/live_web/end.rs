//! The end-of-test diagnosis of `jdbb record --plan --web`: the finished record synchronised
//! with its plan and diagnosed exactly as `jdbb diagnose --record FILE --plan plan.json` does
//! (same functions, default options, no pitch), as the text that command prints.
use std::path::Path;

use crate::circular::diagnose::Options;
use crate::circular::plan::Plan;
use crate::circular::planned::diagnose_record as diagnose_planned_record;
use crate::circular::report::{summary, sync_summary, tolerance_verdict};
use crate::circular::sync::Record;
use crate::Result;

/// Synchronise and diagnose the record at `record` with `plan`; the text `jdbb diagnose --record
/// --plan [--tolerance-um]` prints (synchronisation, diagnosis, verdict).
pub fn diagnose_record(plan: &Plan, record: &Path, tolerance_um: Option<f64>) -> Result<String> {
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
    if let Some(tol) = tolerance_um {
        text.push_str(&tolerance_verdict(&diag, tol).1);
        text.push('\n');
    }
    Ok(text)
}
