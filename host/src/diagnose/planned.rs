//! The diagnosis of a recording of a planned test (`jdbb diagnose --record REC --plan plan.json`):
//! synchronise it ([`crate::sync`]), diagnose its data arcs ([`crate::diagnose`]), and where the
//! diagnosis names errors that depend on the position alone (a cyclic or scale error, a
//! squareness, a bowed axis), read the ramps again through them and diagnose again.
//!
//! Why: the ramps are the synchronisation's rulers, and an error of the machine along a ramp's
//! axis is printed on them — a 1.92 µm, 10 mm-pitch cyclic error stretches the default 2 mm
//! feed-in by 10⁻³, the whole timeline with it, and the stretched timeline is diagnosed as
//! second-order scale and squareness that are not there (issue 20). The diagnosis measures the
//! same errors on the arcs, over the whole circle; taken off the ramps, they leave the ruler
//! true. Passes stop when the feed moves by less than 10⁻⁶ (at most [`MAX_PASSES`]).
//!
//! May use: [`crate::sync`], [`crate::diagnose`], [`crate::model`], [`crate::model::path`].
use crate::diagnose::input::check_holes;
use crate::diagnose::{diagnose, Diagnosis, Options};
use crate::model::path::Path;
use crate::model::{Effect, EffectSet};
use crate::plan::Plan;
use crate::simulate::progress::{Tracker, FIRST_S};
use crate::sync::{check_feed, data_path, synchronise, synchronise_with, Record, Ruler, Sync};
use crate::{Error, Result};

/// Most diagnoses of one record (the first and the re-reads of the ramps).
pub const MAX_PASSES: usize = 4;

/// A planned test's synchronisation, the data the diagnosis took and the diagnosis.
#[derive(Debug, Clone)]
pub struct Planned {
    pub sync: Sync,
    pub path: Path,
    pub d_mm: Vec<f64>,
    pub diagnosis: Diagnosis,
    /// How many times the data were diagnosed (1: the ramps needed no second reading).
    pub passes: usize,
}

/// A record of `plan` as `jdbb diagnose --record --plan` takes it (and the live page at the end
/// of a test): synchronised from D (a record begun after cycle start said as such), its feed
/// and its holes checked, then diagnosed with [`diagnose_planned`]. The one path from a record
/// and its plan to a diagnosis.
pub fn diagnose_record(
    plan: &Plan,
    rec: &Record,
    pitch_mm: [Option<f64>; 3],
    opts: &Options,
) -> Result<Planned> {
    let sync = synchronise(plan, rec).map_err(|e| late_start(plan, rec, e))?;
    check_feed(plan, &sync, rec)?;
    check_holes(rec, &sync)?;
    diagnose_planned(plan, rec, sync, pitch_mm, opts)
}

/// A synchronisation that failed because the record began after cycle start (D already away
/// from the plan's start level in its first seconds) says so and what to do; any other failure
/// is returned as it is.
fn late_start(plan: &Plan, rec: &Record, e: Error) -> Error {
    let mut tracker = Tracker::new(plan);
    for (t, d) in rec.t_s.iter().zip(&rec.d_mm) {
        tracker.push(*t, *d);
        if *t > 2.0 * FIRST_S {
            break;
        }
    }
    match tracker.missed_start {
        Some(m) => Error::Input {
            location: rec.path.display().to_string(),
            message: format!(
                "{m}: the record began after the program started, so it cannot be lined up with the plan. Record again: start `jdbb record --plan` first, then press cycle start ({e})"
            ),
        },
        None => e,
    }
}

/// Diagnose `rec` of `plan`, synchronised as `sync` (module docs); `pitch_mm` as for
/// [`data_path`].
pub fn diagnose_planned(
    plan: &Plan,
    rec: &Record,
    sync: Sync,
    pitch_mm: [Option<f64>; 3],
    opts: &Options,
) -> Result<Planned> {
    let (path, d_mm) = data_path(plan, rec, &sync, pitch_mm)?;
    let diagnosis = diagnose(&path, &d_mm, opts)?;
    let mut out = Planned {
        sync,
        path,
        d_mm,
        diagnosis,
        passes: 1,
    };
    while out.passes < MAX_PASSES {
        let Some(set) = positional(&out.diagnosis) else {
            break;
        };
        let error_mm = |points: &[[f64; 3]]| ruler_error_mm(&set, points, pitch_mm);
        let ruler = Ruler {
            error_mm: &error_mm,
        };
        // A reading that fails (the corrected ramps not found, the data not diagnosed) leaves
        // the last good one: the ruler is a refinement, never a reason to lose the test.
        let Ok(next) = synchronise_with(plan, rec, Some(&ruler)) else {
            break;
        };
        if (next.feed_percent / out.sync.feed_percent - 1.0).abs() < 1e-6 {
            break;
        }
        let Ok((path, d_mm)) = data_path(plan, rec, &next, pitch_mm) else {
            break;
        };
        let Ok(diagnosis) = diagnose(&path, &d_mm, opts) else {
            break;
        };
        out = Planned {
            sync: next,
            path,
            d_mm,
            diagnosis,
            passes: out.passes + 1,
        };
    }
    Ok(out)
}

/// The effects of a diagnosis that depend on the position alone, with their parameters (None
/// without any).
fn positional(d: &Diagnosis) -> Option<(EffectSet, Vec<f64>)> {
    let mut effects = vec![];
    let mut theta = vec![];
    for f in &d.effects {
        if matches!(
            f.effect,
            Effect::Scale(_)
                | Effect::Scale2(_)
                | Effect::Cyclic(_)
                | Effect::Squareness(_)
                | Effect::Straightness(..)
                | Effect::ScaleMismatch(_)
        ) {
            effects.push(f.effect);
            theta.extend(&f.params);
        }
    }
    (!effects.is_empty()).then(|| (EffectSet::new(effects), theta))
}

/// D's error (mm) that the effects `set` make at `points` (relative to the table ball, mm).
fn ruler_error_mm(
    set: &(EffectSet, Vec<f64>),
    points: &[[f64; 3]],
    pitch_mm: [Option<f64>; 3],
) -> Vec<f64> {
    if points.len() < 2 {
        return vec![0.0; points.len()];
    }
    let t: Vec<f64> = (0..points.len()).map(|i| i as f64 * 1e-3).collect();
    let path = Path::new(t, points.to_vec(), pitch_mm);
    set.0
        .distances_mm(&path, &set.1)
        .iter()
        .zip(points)
        .map(|(d, p)| d - (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt())
        .collect()
}
