//! `jdbb`, the host side of the J-DBB double ball bar. One folder per concern:
//!
//! | module | what it is for |
//! |---|---|
//! | [`link`] | the instrument connection: frame stream and its accounting, recording, live readout |
//! | [`live_web`] | the live page during a test (`--web`): progress, trace, diagnosis while recording |
//! | [`circular`] | circular tests: effect models, simulation, diagnosis, report and plots |
//! | [`compensate`] | a diagnosis as settings of a CNC controller (LinuxCNC, grblHAL, Marlin, Klipper) |
//! | [`history`] | a machine's diagnoses over time in one SQLite file; trends |
//! | [`rotary`] | rotary axes (seed 002): six geometric errors; angle-indexed run diagnosis |
//! | [`rrsps`] | the A/C table as an RRSPS linkage (seed 004): design, synthesis, identification |
//! | [`volumetric`] | the volumetric test from one table ball: identifiability, the plan of cones and arcs |
//! | [`instrument`] | the instrument's own calibration from a calibrator's samples; records recomputed |
//! | [`numerics`] | least squares, minimax, forward selection: used by all of the above |
//! | [`table`] | the one reader of CSV tables (named columns, `file:line:col` errors) |
//! | [`cli`] | the command line: one file per subcommand, the only code that prints |
//! | [`units`] | ASCII units in files and JSON, symbols for people |
//! | [`dates`] | dates in reports and the history (RFC 3339, UTC) |
//! | [`error`] | the error type and its exit codes |
//! | [`fsio`] | the one writer (no link, no device, whole files, sets, `--force`) and input limits |
//!
//! Dependencies point one way: `cli` → `compensate`, `history`, `live_web`, `volumetric` → `circular`, `rotary`, `rrsps`,
//! `instrument`, `link` → `numerics`,
//! `table` → `jdbb_core` (the instrument model, wire protocol and machine error models shared
//! with the firmware). No module below `cli` prints or reads the command line.
pub mod circular;
pub mod cli;
pub mod compensate;
pub mod dates;
pub mod error;
pub mod fsio;
pub mod history;
pub mod instrument;
pub mod link;
pub mod live_web;
pub mod numerics;
pub mod profile;
pub mod rotary;
pub mod rrsps;
pub mod table;
pub mod units;
pub mod volumetric;

pub use error::{Error, Result};
