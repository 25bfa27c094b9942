//! Calibration samples without a calibrator: a `jdbb record` file of a machine running the
//! program of a plan (best `jdbb plan --calibration-test`: spheres at several distances),
//! synchronised with the plan from D alone ([`crate::sync`]). Each data-arc sample
//! gives the encoders' counts and the ball's nominal position p relative to the table ball;
//! the reference is |p + c| with the set-up offset c fitted alongside the instrument
//! ([`super::fit`]). The machine is taken as perfect: what it does wrong goes into the
//! instrument's terms it is confounded with ([`super::fit::machine_separation`] says which).
use std::path::Path;

use crate::plan::Plan;
use crate::sync::{data_path_within, synchronise, Record, Sync};
use crate::table::Table;
use crate::{Error, Result};
use jdbb_core::calib::Calibration;
use jdbb_core::geometry::Model;

use super::samples::CalSamples;

/// Most data-arc samples a calibration takes: it uses each sample's counts as they are (no bins),
/// so a longer record is refused (record at a lower rate). The diagnosis bins beyond its own,
/// smaller bound ([`crate::sync::MAX_DATA_SAMPLES`]); a calibration also holds the counts.
pub const MAX_CALIBRATION_SAMPLES: usize = 2_000_000;

/// Calibrate from a machine run: synchronise on the record's D, fit, then synchronise again on
/// D recomputed with that fit and fit once more (see [`run_samples`]).
pub fn calibrate_run(
    plan: &Plan,
    record: &Path,
    nominal: &Calibration,
    opts: &super::fit::Options,
) -> Result<super::fit::Calibrated> {
    calibrate_run_noted(plan, record, nominal, opts).map(|(cal, _)| cal)
}

/// [`calibrate_run`], with what the record set aside in words (glitches, samples the recorder
/// marked: [`Record::set_aside_note`]), if anything.
pub fn calibrate_run_noted(
    plan: &Plan,
    record: &Path,
    nominal: &Calibration,
    opts: &super::fit::Options,
) -> Result<(super::fit::Calibrated, Option<String>)> {
    let (samples, _, _) = run_samples(plan, record, None)?;
    samples.check_against(nominal)?;
    let first = super::fit::calibrate(&samples, nominal, opts)?;
    let (samples, _, note) = run_samples(plan, record, Some(&first.calibration))?;
    Ok((super::fit::calibrate(&samples, nominal, opts)?, note))
}

/// The samples of a machine run `record` of `plan`, the synchronisation that found them, and
/// what the record set aside ([`Record::set_aside_note`]).
/// With `recal`, the record's D is first recomputed from the counts with that calibration (a
/// first fit's): the synchronisation reads D alone, and the nominal instrument's micrometres,
/// with a set-up offset, bias where it places the data arcs.
pub fn run_samples(
    plan: &Plan,
    record: &Path,
    recal: Option<&Calibration>,
) -> Result<(CalSamples, Sync, Option<String>)> {
    let mut rec = Record::read(record)?;
    // The counts (Record keeps only time and D).
    let mut table = Table::open(record)?;
    let cols = table.require(&["t_us", "enc1", "enc2"])?;
    let (mut t_us, mut enc1, mut enc2, mut lines) = (vec![], vec![], vec![], vec![]);
    while let Some(row) = table.next_row()? {
        // The samples the record set aside as glitches are left out here too.
        if !rec.holds_line(row.line()) {
            continue;
        }
        t_us.push(row.number(&cols[0])?);
        enc1.push(row.integer(&cols[1])?);
        enc2.push(row.integer(&cols[2])?);
        lines.push(row.line());
    }
    if t_us.len() != rec.t_s.len() {
        return Err(Error::Numerics(format!(
            "{}: read {} rows of counts but {} of D",
            record.display(),
            t_us.len(),
            rec.t_s.len()
        )));
    }
    if let Some(cal) = recal {
        let model = Model::new(cal);
        for (i, d) in rec.d_mm.iter_mut().enumerate() {
            *d = model.distance_mm(enc1[i], enc2[i]);
        }
    }
    let sync = synchronise(plan, &rec)?;
    let (path, _) = data_path_within(plan, &rec, &sync, [None; 3], MAX_CALIBRATION_SAMPLES)?;
    let (mut e1, mut e2, mut p, mut line) = (vec![], vec![], vec![], vec![]);
    for (k, &t) in path.t_s.iter().enumerate() {
        // data_path's times are the record's own unless it averaged bins (very long records).
        let i = rec.t_s.partition_point(|&x| x < t);
        if i >= rec.t_s.len() || rec.t_s[i] != t {
            return Err(Error::Usage(format!(
                "{}: more than {} samples on the data arcs; a calibration takes each sample's counts as they are: record at a lower rate",
                record.display(),
                MAX_CALIBRATION_SAMPLES
            )));
        }
        e1.push(enc1[i]);
        e2.push(enc2[i]);
        p.push(path.p_mm[k]);
        line.push(lines[i]);
    }
    let note = rec.set_aside_note(Some(&sync));
    Ok((
        CalSamples::from_positions(record, e1, e2, p, line),
        sync,
        note,
    ))
}
