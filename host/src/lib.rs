//! `jdbb`, the host side of the J-DBB double ball bar. One folder per concern:
//!
//! | module | what it is for |
//! |---|---|
//! | [`link`] | the instrument connection: frame stream and its accounting, recording, live readout |
//! | [`live_web`] | the live page during a test (`--web`): progress, trace, diagnosis while recording |
//! | [`model`] | a test's nominal path and the candidate machine effects (seed 000), in the trade's words |
//! | [`plan`] | the program a test runs: plan.json and G-code for the controller dialects |
//! | [`sync`] | a recording lined up with its plan from D alone; glitches set aside |
//! | [`simulate`] | a test on a machine with chosen errors; a plan's program run and recorded; progress |
//! | [`diagnose`] | reading a test; circles, G and H; candidate search, selection, exact refit |
//! | [`report`] | a diagnosis as text, JSON, polar plots, HTML and PDF; its JSON read back |
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
//! Dependencies point one way: `cli` → `compensate`, `history`, `live_web`, `volumetric`,
//! `instrument`, `link` → the test folders `report` → `diagnose` → `simulate` → `sync` → `plan`
//! → `model`; these and `rotary`, `rrsps` → `numerics`,
//! `table` → `jdbb_core` (the instrument model, wire protocol and machine error models shared
//! with the firmware). No module below `cli` prints or reads the command line.
pub mod cli;
pub mod compensate;
pub mod dates;
pub mod diagnose;
pub mod error;
pub mod fsio;
pub mod history;
pub mod instrument;
pub mod link;
pub mod live_web;
pub mod model;
pub mod numerics;
pub mod plan;
pub mod profile;
pub mod report;
pub mod rotary;
pub mod rrsps;
pub mod simulate;
pub mod sync;
pub mod table;
pub mod units;
pub mod volumetric;

pub use error::{Error, Result};
