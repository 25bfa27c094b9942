//! The instrument's own calibration (issue 9 §3, §4): which errors the J-DBB as built has (bar
//! lengths, encoder zeros, skew of the pivot axes, disc eccentricity, and with `--extended` the
//! frames' pivot geometry), found from a calibrator's reference lengths, and old records evaluated
//! again with a new calibration.
//!
//! - [`samples`]: reading CAL.csv (`enc1,enc2,d_ref_mm`) and checking it against the nominal
//!   instrument.
//! - [`effects`]: the named instrument effects a calibration may find, their units and how each
//!   maps onto the parameters of `jdbb_core::calib::Calibration`.
//! - [`fit`]: the calibration fit: baseline, forward selection of effects on the Jacobian of the
//!   core model (the same engine as `diagnose`), exact non-linear refit.
//! - [`report`]: the text summary and the documented JSON of a calibration.
//! - [`file`]: calibration TOML files: reading (checked), writing (temp file, then rename).
//! - [`run`]: calibration samples without a calibrator: a record of a machine running a plan's
//!   spheres, with the nominal positions; the set-up offset is fitted alongside.
//! - [`recompute`]: a `jdbb record` file with `d_mm` recomputed from the counts.
//!
//! May use: [`crate::numerics`], [`crate::table`], [`crate::error`], the plan, synchronisation and
//! diagnosis ([`crate::plan`], [`crate::sync`], [`crate::diagnose`], for [`run`]) and `jdbb_core` (the
//! instrument model `geometry` and its parameters `calib`: the model fitted here is the core's,
//! never a copy). [`crate::cli`] uses this module, never the reverse; nothing here prints.
pub mod effects;
pub mod file;
pub mod fit;
pub mod recompute;
pub mod report;
pub mod run;
pub mod samples;

/// One arc second in radians (angles are radians inside, arcsec only in reports).
pub const ARCSEC_RAD: f64 = std::f64::consts::PI / (180.0 * 3600.0);
