//! Circular tests of a machine's linear axes: what the ballbar sees when the spindle ball circles
//! the table ball, which machine errors explain it, and the report.
//!
//! - [`path`]: the nominal path (positions, velocity, direction, pitch phase).
//! - [`model`]: the candidate machine effects (seed 000) and the exact distance
//!   D = |p + δ + c| + e built from them.
//! - [`simulate`]: a circular test on a machine with chosen errors.
//! - [`input`]: reading a test (`t_s,x_mm,y_mm,z_mm,d_mm`, or a record with its path).
//! - [`runs`]: the circles as drawn: plane, angles, runs, G and H, harmonics.
//! - [`zone`]: per circle: conditions and ISO 230-4 G and H with the minimum-zone centre.
//! - [`diagnose`]: baseline, set-up, candidate search and selection, exact refit.
//! - [`words`]: what each effect means in the trade's words (the causes every output shows).
//! - [`report`] (text, JSON) and [`plot`] (polar plot, SVG and PNG) of a diagnosis;
//!   [`document`] reads that JSON back (the input contract of compensation and history);
//!   [`html`] is the report a person reads (`report.html`), [`pdf`] the same page printed.
//! - [`plan`]: the program a test runs (plan.json and G-code for four controller dialects);
//!   [`sync`]: a recording lined up with its plan from D alone (its glitches set aside first,
//!   [`glitch`]); [`planned`]: its diagnosis, the ramps read again through the errors it finds.
//! - [`machine`] (the machine TOML) and [`record_sim`]: a plan's program run on a machine and
//!   recorded as `jdbb record` records it; [`progress`]: where a recording stands against its
//!   plan while it is made.
//!
//! May use: [`crate::numerics`], [`crate::table`], `jdbb_core::machine` (and, for [`plan`],
//! `jdbb_core::{calib, geometry}`). Dependencies inside point one way: model ← simulate, input,
//! runs, zone ← diagnose ← report, plot, html; words ← report, html; plan ← sync ← planned
//! (with input, progress, diagnose); simulate, plan, sync ← machine, record_sim ← progress;
//! document stands alone (it reads files, not diagnoses).
pub mod diagnose;
pub mod document;
pub mod glitch;
pub mod html;
pub mod input;
pub mod machine;
pub mod model;
pub mod path;
pub mod pdf;
pub mod pitch_hint;
pub mod plan;
pub mod planned;
pub mod plot;
pub mod progress;
pub mod record_sim;
pub mod report;
pub mod runs;
pub mod simulate;
pub mod sync;
pub mod timeline;
pub mod words;
pub mod zone;
