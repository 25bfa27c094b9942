//! The program a ballbar test runs: the nominal path of a circular test as the machine will
//! drive it, written as `plan.json` (this module) and as a G-code program for one controller
//! dialect ([`gcode`]). `jdbb plan` (`cli/plan.rs`) is the command; the synchronisation of a
//! recording with its plan reads `plan.json` through [`Plan::read`], [`Plan::position_at`] and
//! [`Plan::length_mm`].
//!
//! # The motion (ISO 230-4 style)
//!
//! Plane axes (i, j) and normal n: `xy` = (x, y; z), `yz` = (y, z; x), `zx` = (z, x; y), all
//! right-handed, so **ccw** means the angle θ = atan2(j, i) grows: a rotation about +n. Circle k
//! has its centre at `--centre` + H·n̂ (H = its height), radius R, start angle θ0 (`--start-deg`,
//! default 0: on +i). Per height, per radius, in the order given (the calibration test: see
//! below), each circle is:
//!
//! 1. to the feed-in start P_in = c + (R − f)(cos θ0 î + sin θ0 ĵ), f = `--feed-in-mm`: for the
//!    first circle a **rapid** (G0) followed by a **program stop** (M0) — there the operator mounts
//!    the instrument and presses cycle start; for the next circles a move at the feed, with the
//!    instrument still mounted (the J-DBB's radius is free: no re-mounting). A move is one line,
//!    or a few lines along a spiral in the (radius, height) half-plane at θ0 when a straight line
//!    would bring the balls closer than the instrument allows (role `move`);
//! 2. a dwell of `--dwell-s` (G4): a standstill the synchronisation can find in D;
//! 3. the feed-in: a line from P_in to the circle at θ0 (D changes by about f·R/D), and a dwell of
//!    `--corner-dwell-s` (default 0.1 s) at the corner, so that every controller stops there
//!    (grbl and Marlin would pass it at their junction speed);
//! 4. counter-clockwise: the lead-in arc (θ0 → θ0 + L, L = `--lead-in-deg`), the data arc of
//!    360°, the overshoot arc of O = `--overshoot-deg`;
//! 5. a dwell of `--reversal-dwell-s` (default: `--dwell-s`) at the reversal;
//! 6. clockwise: lead-in L, data 360°, overshoot O, ending at θ0 again, and a dwell of
//!    `--corner-dwell-s`;
//! 7. the feed-out: a line back to P_in, and a dwell of `--dwell-s`.
//!
//! **Partial arcs** (`--arc-deg A`, 0 < A < 360; default 360, the full circle above): the
//! machine never leaves the arc [θ0, θ0 + A] — in a vertical plane a full circle would run the
//! spindle into the table, and the ballbar test there is 220° (`--start-deg -20 --arc-deg 220`:
//! −20° to 200° from the plane's first axis). The lead-in and overshoot cannot reach past the
//! arc's ends, so they are taken **from inside it** (default L = O = 20° on a partial arc):
//! step 4 is lead-in θ0 → θ0 + L, data θ0 + L → θ0 + A − O, overshoot up to θ0 + A; step 6 runs
//! the same arc back, θ0 + A → θ0 + A − O (the cw lead-in), the data arc cw, θ0 + L → θ0 (the
//! cw overshoot). **The data arc is [θ0 + L, θ0 + A − O]** (180° for the 220° test: 0° to 180°),
//! both senses; L + O < A, else the plan is refused. Both ends of the arc are axis reversals of
//! every moving axis (the sense reverses there), and the lead-in and overshoot keep the steps,
//! dead bands and spikes of those reversals off the data arc. `--lead-in-deg 0 --overshoot-deg
//! 0` makes the data arc the whole arc (then the data start from rest, and a run of the 220° test
//! so planned named a 0.05 µm reversal spike that was not there). The synchronisation needs the
//! feed-in of a partial arc to reach the feed ([`crate::sync`]): `jdbb plan` says so
//! when `--feed-in-mm` is short for the feed.
//!
//! A dwell of 0 s is left out. Arcs are split into equal pieces of at most 180° (a full circle or
//! an arc over 180° is ambiguous or controller-dependent with I/J/K), so with the defaults
//! (L = O = 180°) each direction is 4 arcs of 180°, and every arc end lies on an axis of its
//! circle; on the 220° test each direction is 20°, 180° and 20°, and the ends at −20° and 200°
//! are off the axes, rounded to the grid (below).
//!
//! **Range.** D = √(R² + H²) on a circle; every point the program visits with the instrument
//! mounted — circles, feed-in starts, moves between circles — stays within the instrument's range
//! [`Instrument`]: D_min = D at the frames' ±75° ([`FRAME_RANGE_RAD`], the worst lean azimuth puts
//! the whole deflection on one frame) and D_max = L1 + L2 (bars straight), each brought in by
//! [`RANGE_MARGIN_MM`] for set-up error, from the calibration ([`Calibration::DEFAULT`] or
//! `--calibration CAL.toml`). A plan that would leave it is refused with the range in the message.
//! The range is not checked on the first rapid: the instrument is mounted after it.
//!
//! **Grid.** Every position in the plan and the program is on a 1 µm grid ([`GRID_MM`]: Fanuc's
//! IS-B least input increment, the finest all four dialects take), so the program's numbers are
//! the plan's numbers exactly; radii, heights and the centre are rounded to it. An arc end at an
//! angle that is not a multiple of 90° moves along its circle (at most [`ON_CIRCLE_SEARCH_DEG`])
//! to a grid point on the circle (within [`ON_CIRCLE_NM`]): rounded where the angle says, it would
//! be up to 0.71 µm off the circle, and a controller would draw a spiral or a step that the
//! ballbar sees (`build::on_circle`). Feeds are rounded to 0.001 mm/min and dwells to 1 ms.
//!
//! # The calibration test (`--calibration-test`, purpose `calibration-test`)
//!
//! Spheres at several ball distances D (`--distance`, default 4 spread over the range): on each
//! sphere, circles at the latitudes [`CALIBRATION_LATITUDES_DEG`] (0°, 30°, 60° towards +n:
//! R = D cos λ, H = D sin λ; in plane xy the spindle ball stays level with or above the table
//! ball), each run
//! as above, spheres in order and latitudes alternately up and down so moves stay short. What it
//! covers: the deflection φ(D) at every distance — by default from about 12° to 69° with 50 mm
//! bars, most of the frames' ±75° — and for each, the bar direction B1→B2 over all azimuths and
//! elevations 0–60°, which turns the knee about both frame axes. What it cannot set: the knee's
//! lean azimuth about the B1–B2 line (gravity and the bars' spin in their cups decide it), so the
//! split of φ between the two frames is measured, not planned.
//!
//! # plan.json (version 2)
//!
//! ```json
//! {
//!   "format": "jdbb-plan", "version": 2, "purpose": "machine-test",
//!   "program": "ballbar.ngc", "dialect": "linuxcnc", "units": "mm", "plane": "xy",
//!   "centre_mm": [100.0, 50.0, -20.0], "feed_mm_min": 1000.0,
//!   "instrument": {"l1_mm": 50.0, "l2_mm": 50.0, "frame_range_deg": 75.0, "margin_mm": 0.5,
//!                  "d_min_mm": 79.836, "d_max_mm": 99.5},
//!   "start_mm": [188.0, 50.0, -20.0],
//!   "arc": {"start_deg": 0.0, "sweep_deg": 360.0, "lead_in_deg": 180.0, "overshoot_deg": 180.0,
//!           "data_start_deg": 180.0, "data_sweep_deg": 360.0},
//!   "circles": [{"index": 0, "radius_mm": 90.0, "height_mm": 0.0, "centre_mm": [100.0, 50.0, -20.0],
//!                "d_mm": 90.0, "plane": "xy", "feed_mm_min": 1000.0}],
//!   "segments": [
//!     {"kind": "rapid", "from_mm": [188.0, 50.0, -20.0], "to_mm": [188.0, 50.0, -20.0]},
//!     {"kind": "stop"},
//!     {"kind": "dwell", "seconds": 1.0},
//!     {"kind": "line", "from_mm": [188.0, 50.0, -20.0], "to_mm": [190.0, 50.0, -20.0],
//!      "feed_mm_min": 1000.0, "role": "feed_in", "circle": 0},
//!     {"kind": "dwell", "seconds": 0.1},
//!     {"kind": "arc", "circle": 0, "centre_mm": [100.0, 50.0, -20.0], "radius_mm": 90.0,
//!      "plane": "xy", "sense": "ccw", "start_deg": 0.0, "sweep_deg": 180.0,
//!      "feed_mm_min": 1000.0, "role": "lead_in", "from_mm": [190.0, 50.0, -20.0],
//!      "to_mm": [10.0, 50.0, -20.0]}
//!   ]
//! }
//! ```
//!
//! - `purpose`: `machine-test` or `calibration-test`; `dialect`: `linuxcnc`, `grbl`, `fanuc`,
//!   `marlin`; `program`: the program file beside plan.json (see [`Dialect::program_name`]).
//! - Positions are program (machine) coordinates in mm; the diagnosis works relative to the
//!   table ball: subtract `centre_mm`. `start_mm` is where the operator mounts the instrument.
//! - `instrument`: bar lengths, the frames' range, the margin, and the range of D every mounted
//!   segment keeps (margin included).
//! - `arc` (new in version 2): the arc every circle runs, in degrees from the plane's first axis
//!   towards the second — `start_deg` θ0 (as given), `sweep_deg` A (360: a full circle),
//!   `lead_in_deg` L, `overshoot_deg` O, and the data arc: from `data_start_deg` (θ0 + L) over
//!   `data_sweep_deg` (360 on a full circle, A − L − O on a partial arc), in both senses. A
//!   version-1 plan (before partial arcs) is read as a full circle, its arc taken from its first
//!   circle's segments.
//! - `close` (`first`, `abba`; absent: not closed): how the test closes on itself in time
//!   ([`Close`], `jdbb plan --close`): `circles` are listed in execution order, so a closed test
//!   lists a radius twice.
//! - `segments` are in execution order and tile the program's motion exactly: every G0, G1, G2,
//!   G3, G4 and M0 of the program is one segment, in order, and each motion starts where the
//!   previous one ended. `rapid` (G0; the first segment; its `from_mm` is its `to_mm`, because
//!   the machine's position before the program is unknown — nothing is measured before the stop),
//!   `stop` (M0: the operator, unknown duration), `dwell` (`seconds`), `line` (G1; `role`
//!   `feed_in`, `feed_out` or `move`; `circle`: the circle it belongs to, for a move the one it
//!   goes to), `arc` (G2/G3 of at most 180°: `centre_mm`, `radius_mm`, `plane`, `sense` `ccw`/`cw`,
//!   `start_deg` in [0, 360) from +i towards +j, `sweep_deg` signed (+ ccw, − cw), `role`
//!   `lead_in`, `data` or `overshoot`).
//! - Version 3 (purpose `volumetric-test`, [`crate::volumetric`]): the same fields; its circles
//!   are of several planes (`plane` per circle; the plan's `plane` and `arc` are its first
//!   circle's) and each carries its own `arc` (the fields of the plan's `arc`).
//! - Times are not in plan.json: the machine decides them. [`Plan::nominal_duration_s`] is the
//!   feed-rate estimate.
//!
//! May use: `jdbb_core::{calib, geometry}`, [`crate::table`]. Inside: [`build`] makes a plan
//! from a [`PlanSpec`], [`gcode`] writes it.
//!
//! The folder `plan/`: [`build`] makes a plan, [`gcode`] writes its program for four controller
//! dialects. May use: [`crate::model`] (below it), `jdbb_core::{calib, geometry}`; nothing of
//! `sync`, `simulate`, `diagnose` or `report` (which use it).
use std::path::Path;

use jdbb_core::calib::Calibration;
use jdbb_core::geometry::{deflection_for_distance_rad, distance_from_deflection_mm};
use serde::{Deserialize, Serialize};

use crate::{Error, Result};

pub mod build;
pub mod gcode;

pub use build::{
    calibration_circles, default_calibration_distances, default_lead_in_overshoot,
    machine_test_circles, plan, CircleSpec, PlanSpec, ON_CIRCLE_NM, ON_CIRCLE_SEARCH_DEG,
};
pub use gcode::write_program;
pub use jdbb_core::geometry::FRAME_RANGE_RAD;

/// The `format` of a plan.json.
pub const FORMAT: &str = "jdbb-plan";
/// The plan.json version this code writes (it reads this one and version 1, which had no `arc`:
/// every circle full).
pub const VERSION: u32 = 2;
/// The plan.json version of a volumetric test (purpose `volumetric-test`): version 2 with
/// circles of several planes, each with its own `arc` ([`Circle::arc`]). Plane tests are still
/// written as version 2, so their files and ids are unchanged.
pub const VOLUMETRIC_VERSION: u32 = 3;
/// Grid of every position in a plan and its program (mm): 1 µm.
pub const GRID_MM: f64 = 0.001;
/// How far inside the instrument's mechanical range every D of a plan stays (mm), for set-up
/// error: the table ball not exactly at `--centre`, the machine's own error.
pub const RANGE_MARGIN_MM: f64 = 0.5;
/// Largest arc of one G2/G3 block (degrees).
pub const MAX_ARC_DEG: f64 = 180.0;
/// Latitudes of the circles on each sphere of the calibration test (degrees towards +n).
pub const CALIBRATION_LATITUDES_DEG: [f64; 3] = [0.0, 30.0, 60.0];

/// The plane of a circle: axes (i, j) and the normal n, right-handed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Plane {
    /// (x, y), normal z: G17.
    Xy,
    /// (y, z), normal x: G19.
    Yz,
    /// (z, x), normal y: G18.
    Zx,
}

impl Plane {
    /// Indices (i, j, n) of the plane's axes and its normal (x = 0, y = 1, z = 2).
    pub fn axes(self) -> (usize, usize, usize) {
        match self {
            Plane::Xy => (0, 1, 2),
            Plane::Yz => (1, 2, 0),
            Plane::Zx => (2, 0, 1),
        }
    }

    /// `xy`, `yz` or `zx`.
    pub fn name(self) -> &'static str {
        match self {
            Plane::Xy => "xy",
            Plane::Yz => "yz",
            Plane::Zx => "zx",
        }
    }

    /// The plane called `xy`, `yz` or `zx`.
    pub fn parse(s: &str) -> Option<Plane> {
        [Plane::Xy, Plane::Yz, Plane::Zx]
            .into_iter()
            .find(|p| p.name().eq_ignore_ascii_case(s.trim()))
    }
}

/// A controller's G-code dialect (see [`gcode`] for what differs).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Dialect {
    /// LinuxCNC (RS274/NGC).
    Linuxcnc,
    /// grbl 1.1 (and grblHAL).
    Grbl,
    /// Fanuc 0i/30i family, milling.
    Fanuc,
    /// Marlin 2 with `ARC_SUPPORT`.
    Marlin,
}

impl Dialect {
    /// Every dialect, in the order the help lists them.
    pub const ALL: [Dialect; 4] = [
        Dialect::Linuxcnc,
        Dialect::Grbl,
        Dialect::Fanuc,
        Dialect::Marlin,
    ];

    /// `linuxcnc`, `grbl`, `fanuc` or `marlin`.
    pub fn name(self) -> &'static str {
        match self {
            Dialect::Linuxcnc => "linuxcnc",
            Dialect::Grbl => "grbl",
            Dialect::Fanuc => "fanuc",
            Dialect::Marlin => "marlin",
        }
    }

    /// The dialect called `name`.
    pub fn parse(name: &str) -> Option<Dialect> {
        Dialect::ALL
            .into_iter()
            .find(|d| d.name().eq_ignore_ascii_case(name.trim()))
    }

    /// The program's file name beside plan.json: `ballbar.ngc` (LinuxCNC), `ballbar.nc` (grbl),
    /// `O1000.nc` (Fanuc: program number O1000), `ballbar.gcode` (Marlin).
    pub fn program_name(self) -> &'static str {
        match self {
            Dialect::Linuxcnc => "ballbar.ngc",
            Dialect::Grbl => "ballbar.nc",
            Dialect::Fanuc => "O1000.nc",
            Dialect::Marlin => "ballbar.gcode",
        }
    }
}

/// How a test closes on itself in time (`jdbb plan --close`, `close` in plan.json): heat grows an
/// axis's scale during the test, and circles run one after the other cannot tell a scale that
/// grows in time from one that depends on the radius. Running a circle again later can.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum Close {
    /// The circles once each, in the order given (as before: growth in time and dependence on
    /// radius are confounded on more than one circle).
    #[default]
    None,
    /// The first circle again at the end: A B … A.
    First,
    /// The circles in order, then in reverse: A B B A (ABBA), each circle's mean time the same.
    Abba,
}

impl Close {
    /// Whether the test does not close on itself.
    pub fn is_none(&self) -> bool {
        *self == Close::None
    }

    /// `none`, `first` or `abba`.
    pub fn name(self) -> &'static str {
        match self {
            Close::None => "none",
            Close::First => "first",
            Close::Abba => "abba",
        }
    }

    /// The circles to run, in execution order, for `circles` given in order.
    pub fn order<T: Clone>(self, circles: &[T]) -> Vec<T> {
        let mut v = circles.to_vec();
        match self {
            Close::None => {}
            Close::First => v.extend(circles.first().cloned()),
            Close::Abba => v.extend(circles.iter().rev().cloned()),
        }
        v
    }
}

/// What a plan is for.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Purpose {
    /// Circles of the given radii and heights: the machine's errors.
    MachineTest,
    /// Spheres at several ball distances: the instrument's calibration.
    CalibrationTest,
    /// Cones and arcs of several planes about one table ball: all three axes from one mount
    /// ([`crate::volumetric`]; plan.json version [`VOLUMETRIC_VERSION`]).
    VolumetricTest,
}

impl Purpose {
    /// `machine-test` or `calibration-test`.
    pub fn name(self) -> &'static str {
        match self {
            Purpose::MachineTest => "machine-test",
            Purpose::CalibrationTest => "calibration-test",
            Purpose::VolumetricTest => "volumetric-test",
        }
    }
}

/// Direction of an arc, seen from the positive end of the plane's normal.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Sense {
    /// Counter-clockwise: θ = atan2(j, i) grows (G3).
    Ccw,
    /// Clockwise: θ falls (G2).
    Cw,
}

/// What a line is for.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum LineRole {
    /// From the feed-in start onto the circle.
    FeedIn,
    /// From the circle back to the feed-in start.
    FeedOut,
    /// Between two circles' feed-in starts.
    Move,
}

/// What an arc is for.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ArcRole {
    /// Before the data arc: the machine reaches steady motion.
    LeadIn,
    /// The arc the diagnosis uses: 360° on a full circle, [θ0 + L, θ0 + A − O] on a partial arc.
    Data,
    /// After the data arc, before the reversal or the feed-out.
    Overshoot,
}

/// The instrument's range as a plan uses it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Instrument {
    /// Bar 1 (table ball to joint), mm.
    pub l1_mm: f64,
    /// Bar 2 (joint to spindle ball), mm.
    pub l2_mm: f64,
    /// Each frame's range, ± degrees.
    pub frame_range_deg: f64,
    /// Margin kept inside the mechanical range at both ends, mm.
    pub margin_mm: f64,
    /// Smallest D any mounted segment reaches (margin included), mm.
    pub d_min_mm: f64,
    /// Largest D any mounted segment reaches (margin included), mm.
    pub d_max_mm: f64,
}

/// The range of D for a calibration: D at the frames' limit ([`FRAME_RANGE_RAD`]) up to
/// L1 + L2, each brought in by [`RANGE_MARGIN_MM`] and rounded inwards to the grid.
pub fn instrument(cal: &Calibration) -> Result<Instrument> {
    cal.validate().map_err(|e| {
        Error::Usage(format!(
            "the calibration is not usable ({e:?}): bar lengths must be between 1 mm and 10 m, encoders at least 4 counts per revolution"
        ))
    })?;
    let (l1, l2) = (cal.l1_mm, cal.l2_mm);
    let lo = distance_from_deflection_mm(l1, l2, FRAME_RANGE_RAD) + RANGE_MARGIN_MM;
    let hi = distance_from_deflection_mm(l1, l2, 0.0) - RANGE_MARGIN_MM;
    let d_min_mm = (lo * 1000.0).ceil() / 1000.0;
    let d_max_mm = (hi * 1000.0).floor() / 1000.0;
    if d_min_mm >= d_max_mm {
        return Err(Error::Usage(format!(
            "bars of {l1} mm and {l2} mm leave no usable range of D inside the frames' ±75° and the {RANGE_MARGIN_MM} mm margin"
        )));
    }
    Ok(Instrument {
        l1_mm: l1,
        l2_mm: l2,
        frame_range_deg: FRAME_RANGE_RAD.to_degrees(),
        margin_mm: RANGE_MARGIN_MM,
        d_min_mm,
        d_max_mm,
    })
}

impl Instrument {
    /// Joint deflection φ (degrees) at ball distance `d_mm`, or `None` out of reach.
    pub fn deflection_deg(&self, d_mm: f64) -> Option<f64> {
        deflection_for_distance_rad(self.l1_mm, self.l2_mm, d_mm).map(f64::to_degrees)
    }

    /// Whether `d_mm` is inside the range (with 1 nm for rounding).
    pub fn contains(&self, d_mm: f64) -> bool {
        d_mm >= self.d_min_mm - 1e-6 && d_mm <= self.d_max_mm + 1e-6
    }

    /// The range as a message names it: `79.836..99.500 mm (L1 50 mm, L2 50 mm, frames ±75°,
    /// 0.5 mm margin)`.
    pub fn describe(&self) -> String {
        format!(
            "{:.3}..{:.3} mm (L1 {} mm, L2 {} mm, frames ±{}°, {} mm margin)",
            self.d_min_mm,
            self.d_max_mm,
            self.l1_mm,
            self.l2_mm,
            self.frame_range_deg.round(),
            self.margin_mm
        )
    }
}

/// The arc every circle of a plan runs (degrees from the plane's first axis towards the second;
/// see the module docs).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct CircleArc {
    /// θ0: where each circle starts and ends.
    pub start_deg: f64,
    /// A: 360 for a full circle, less for a partial arc [θ0, θ0 + A].
    pub sweep_deg: f64,
    /// L: the lead-in (on a partial arc from inside the arc).
    pub lead_in_deg: f64,
    /// O: the overshoot (on a partial arc from inside the arc).
    pub overshoot_deg: f64,
    /// Where the data arc starts (ccw): θ0 + L.
    pub data_start_deg: f64,
    /// The data arc's length: 360 on a full circle, A − L − O on a partial arc.
    pub data_sweep_deg: f64,
}

impl CircleArc {
    /// Whether the circles run a partial arc.
    pub fn is_partial(&self) -> bool {
        self.sweep_deg < 360.0
    }

    /// The arc of a version-1 plan (full circles, from before `arc` existed), from the first
    /// circle's ccw arcs: θ0 where its first arc starts, L and O the sums of its ccw lead-in
    /// and overshoot sweeps.
    fn of_full_circles(segments: &[Segment]) -> CircleArc {
        let ccw = |want: ArcRole| {
            segments
                .iter()
                .filter_map(|s| match s {
                    Segment::Arc {
                        circle: 0,
                        sense: Sense::Ccw,
                        role,
                        sweep_deg,
                        ..
                    } if *role == want => Some(*sweep_deg),
                    _ => None,
                })
                .sum::<f64>()
        };
        let start_deg = segments
            .iter()
            .find_map(|s| match s {
                Segment::Arc { start_deg, .. } => Some(*start_deg),
                _ => None,
            })
            .unwrap_or(0.0);
        let lead_in_deg = ccw(ArcRole::LeadIn);
        CircleArc {
            start_deg,
            sweep_deg: 360.0,
            lead_in_deg,
            overshoot_deg: ccw(ArcRole::Overshoot),
            data_start_deg: start_deg + lead_in_deg,
            data_sweep_deg: 360.0,
        }
    }
}

/// One circle of a plan.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Circle {
    /// Position in `circles` (0-based), as segments refer to it.
    pub index: usize,
    pub radius_mm: f64,
    /// Along the plane's normal, from the table ball.
    pub height_mm: f64,
    /// `centre_mm` of the plan + height along the normal.
    pub centre_mm: [f64; 3],
    /// Ball distance on the circle, √(R² + H²).
    pub d_mm: f64,
    pub plane: Plane,
    pub feed_mm_min: f64,
    /// The arc this circle runs, in a volumetric plan (version 3), whose circles run different
    /// arcs in different planes; absent in a plane test, whose circles all run the plan's `arc`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub arc: Option<CircleArc>,
}

/// One block of the program (see the module docs for the fields).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum Segment {
    /// G0 to the start point, before the instrument is mounted.
    Rapid { from_mm: [f64; 3], to_mm: [f64; 3] },
    /// M0: the operator mounts the instrument; unknown duration.
    Stop,
    /// G4.
    Dwell { seconds: f64 },
    /// G1.
    Line {
        from_mm: [f64; 3],
        to_mm: [f64; 3],
        feed_mm_min: f64,
        role: LineRole,
        circle: usize,
    },
    /// G2 (cw) or G3 (ccw), at most 180°.
    Arc {
        circle: usize,
        centre_mm: [f64; 3],
        radius_mm: f64,
        plane: Plane,
        sense: Sense,
        start_deg: f64,
        sweep_deg: f64,
        feed_mm_min: f64,
        role: ArcRole,
        from_mm: [f64; 3],
        to_mm: [f64; 3],
    },
}

impl Segment {
    /// Where a motion starts, `None` for a stop or a dwell.
    pub fn from_mm(&self) -> Option<[f64; 3]> {
        match self {
            Segment::Rapid { from_mm, .. }
            | Segment::Line { from_mm, .. }
            | Segment::Arc { from_mm, .. } => Some(*from_mm),
            Segment::Stop | Segment::Dwell { .. } => None,
        }
    }

    /// Where a motion ends, `None` for a stop or a dwell.
    pub fn to_mm(&self) -> Option<[f64; 3]> {
        match self {
            Segment::Rapid { to_mm, .. }
            | Segment::Line { to_mm, .. }
            | Segment::Arc { to_mm, .. } => Some(*to_mm),
            Segment::Stop | Segment::Dwell { .. } => None,
        }
    }

    /// Path length (mm): 0 for a stop or a dwell; an arc's R·|sweep|.
    pub fn length_mm(&self) -> f64 {
        match self {
            Segment::Rapid { from_mm, to_mm } | Segment::Line { from_mm, to_mm, .. } => {
                dist(from_mm, to_mm)
            }
            Segment::Arc {
                radius_mm,
                sweep_deg,
                ..
            } => radius_mm * sweep_deg.to_radians().abs(),
            Segment::Stop | Segment::Dwell { .. } => 0.0,
        }
    }

    /// Nominal duration (s) at the programmed feed: none for a rapid or a stop (the machine
    /// decides them).
    pub fn nominal_duration_s(&self) -> Option<f64> {
        match self {
            Segment::Line { feed_mm_min, .. } | Segment::Arc { feed_mm_min, .. } => {
                Some(self.length_mm() / feed_mm_min * 60.0)
            }
            Segment::Dwell { seconds } => Some(*seconds),
            Segment::Rapid { .. } | Segment::Stop => None,
        }
    }
}

/// Euclidean distance of two points (mm).
pub fn dist(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    let d = [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
    (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt()
}

/// Smallest and largest D (mm) on the straight segment a → b, the table ball at `c`.
pub fn line_d_range(c: &[f64; 3], a: &[f64; 3], b: &[f64; 3]) -> (f64, f64) {
    let ab: [f64; 3] = std::array::from_fn(|k| b[k] - a[k]);
    let ac: [f64; 3] = std::array::from_fn(|k| c[k] - a[k]);
    let len2 = ab.iter().map(|x| x * x).sum::<f64>();
    let t = if len2 > 0.0 {
        (ab.iter().zip(&ac).map(|(x, y)| x * y).sum::<f64>() / len2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    let closest: [f64; 3] = std::array::from_fn(|k| a[k] + t * ab[k]);
    let (da, db) = (dist(c, a), dist(c, b));
    (dist(c, &closest), da.max(db))
}

/// The key of the comment line `# plan_id: …` before a record's header: the [`Plan::id`] of the
/// plan the record was made for.
pub const PLAN_ID_KEY: &str = "plan_id";

/// A test's program as data: plan.json (see the module docs). An unknown key is an error naming
/// it (a misspelled key is not a value silently left out).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Plan {
    /// Always [`FORMAT`].
    pub format: String,
    /// [`VERSION`].
    pub version: u32,
    pub purpose: Purpose,
    /// The program's file name, beside plan.json.
    pub program: String,
    pub dialect: Dialect,
    /// Always `mm`.
    pub units: String,
    pub plane: Plane,
    /// The table ball's centre in program coordinates.
    pub centre_mm: [f64; 3],
    pub feed_mm_min: f64,
    pub instrument: Instrument,
    /// Where the operator mounts the instrument (the first feed-in start).
    pub start_mm: [f64; 3],
    /// The arc every circle runs (version 2; filled in from the segments for version 1).
    pub arc: CircleArc,
    /// How the test closes on itself in time ([`Close`]). `none` is not written, so a plan that
    /// does not close is the plan.json, and has the [`Plan::id`], it had before `close` existed.
    #[serde(default, skip_serializing_if = "Close::is_none")]
    pub close: Close,
    pub circles: Vec<Circle>,
    pub segments: Vec<Segment>,
}

impl Plan {
    /// The feeds the circles run at (mm/min), each once in the order first run: one, or the
    /// feeds of a feed sweep; the plan's feed for a plan without circles.
    pub fn feeds_mm_min(&self) -> Vec<f64> {
        let mut feeds: Vec<f64> = vec![];
        for c in &self.circles {
            if !feeds.contains(&c.feed_mm_min) {
                feeds.push(c.feed_mm_min);
            }
        }
        if feeds.is_empty() {
            feeds.push(self.feed_mm_min);
        }
        feeds
    }

    /// Read a plan.json. Malformed JSON, another format or version, or segments that do not
    /// chain are bad input (exit 2) naming `file:line:col` where known.
    pub fn read(path: &Path) -> Result<Plan> {
        Plan::from_json(path, &crate::table::read_text(path)?)
    }

    /// Parse plan.json text; `path` names it in errors.
    pub fn from_json(path: &Path, text: &str) -> Result<Plan> {
        // The format and version first, so another file's shape is reported as what it is.
        let head: serde_json::Value =
            serde_json::from_str(text).map_err(|e| json_error(path, &e))?;
        if head.get("format").and_then(|f| f.as_str()) != Some(FORMAT) {
            return Err(Error::input(
                path,
                1,
                0,
                format!("not a plan: `format` is not \"{FORMAT}\"; write one with `jdbb plan`"),
            ));
        }
        let version = head.get("version").and_then(|v| v.as_u64());
        if version != Some(VERSION as u64)
            && version != Some(1)
            && version != Some(VOLUMETRIC_VERSION as u64)
        {
            return Err(Error::input(
                path,
                1,
                0,
                format!(
                    "plan version {} is not 1, {VERSION} or {VOLUMETRIC_VERSION}, the versions this jdbb reads; make the plan again with this jdbb",
                    head.get("version").map_or("missing".into(), |v| v.to_string())
                ),
            ));
        }
        let plan: Plan = if version == Some(1) {
            // Version 1 had no `arc`: full circles, whose arc the segments tell.
            let v1: PlanV1 = serde_json::from_str(text).map_err(|e| json_error(path, &e))?;
            v1.into_plan()
        } else {
            serde_json::from_str(text).map_err(|e| json_error(path, &e))?
        };
        if !(plan.arc.sweep_deg > 0.0
            && plan.arc.sweep_deg <= 360.0
            && plan.arc.data_sweep_deg > 0.0
            && plan.arc.data_sweep_deg <= 360.0
            && plan.arc.start_deg.is_finite()
            && plan.arc.data_start_deg.is_finite())
        {
            return Err(Error::input(
                path,
                1,
                0,
                "`arc` is not an arc of above 0° and at most 360° with a data arc inside; make the plan again with `jdbb plan`".to_string(),
            ));
        }
        plan.check_chain()
            .and_then(|()| plan.check_circles())
            .map_err(|m| {
                Error::input(
                    path,
                    1,
                    0,
                    format!("{m}; make the plan again with `jdbb plan`"),
                )
            })?;
        Ok(plan)
    }

    /// Pretty JSON (plan.json's text, with a final newline).
    pub fn to_json(&self) -> String {
        let mut s = serde_json::to_string_pretty(self).expect("a plan is plain data");
        s.push('\n');
        s
    }

    /// The circles and units agree with the segments: `units` is mm; each circle is where its
    /// index says, with D = √(R² + H²) and the plan's plane; each arc of a circle has that
    /// circle's centre, radius and plane and runs on it (to 1 µm).
    fn check_circles(&self) -> std::result::Result<(), String> {
        const TOL_MM: f64 = 1e-3;
        if self.units != "mm" {
            return Err(format!(
                "`units` is \"{}\"; a plan's numbers are in mm",
                self.units
            ));
        }
        // A volumetric plan (and only it) has circles of several planes, each with its arc.
        let volumetric = self.purpose == Purpose::VolumetricTest;
        if volumetric != (self.version == VOLUMETRIC_VERSION) {
            return Err(format!(
                "purpose {} does not go with version {}: a volumetric test is version {VOLUMETRIC_VERSION}, other tests 1 or {VERSION}",
                self.purpose.name(),
                self.version
            ));
        }
        for (k, c) in self.circles.iter().enumerate() {
            let d = c.radius_mm.hypot(c.height_mm);
            if c.index != k
                || !(c.radius_mm > 0.0 && c.radius_mm.is_finite())
                || (c.d_mm - d).abs().partial_cmp(&TOL_MM) != Some(std::cmp::Ordering::Less)
                || (!volumetric && c.plane != self.plane)
                || volumetric != c.arc.is_some()
            {
                return Err(format!(
                    "circle {k} does not agree with itself (index, radius, D = √(R² + H²), plane, arc)"
                ));
            }
        }
        for (k, s) in self.segments.iter().enumerate() {
            if let Segment::Arc {
                circle,
                centre_mm,
                radius_mm,
                plane,
                from_mm,
                to_mm,
                ..
            } = s
            {
                let c = &self.circles[*circle];
                let on = |p: &[f64; 3]| (dist(p, centre_mm) - radius_mm).abs() <= TOL_MM;
                if (radius_mm - c.radius_mm).abs() > TOL_MM
                    || dist(centre_mm, &c.centre_mm) > TOL_MM
                    || *plane != c.plane
                    || !on(from_mm)
                    || !on(to_mm)
                {
                    return Err(format!(
                        "segment {k} is an arc of circle {circle} but not on it (centre, radius or plane differ from `circles`)"
                    ));
                }
            }
        }
        Ok(())
    }

    /// The structure [`Plan::position_at`] relies on: a program file name beside plan.json, a
    /// rapid first, circles the segments refer to, finite numbers, and every motion starting
    /// where the previous one ended.
    fn check_chain(&self) -> std::result::Result<(), String> {
        if self.program.is_empty() || self.program.contains(['/', '\\']) || self.program == ".." {
            return Err(format!(
                "`program` is \"{}\", not a file name beside plan.json",
                self.program
            ));
        }
        if !matches!(self.segments.first(), Some(Segment::Rapid { .. })) {
            return Err("the first segment is not the rapid to the start point".into());
        }
        let mut at: Option<[f64; 3]> = None;
        for (k, s) in self.segments.iter().enumerate() {
            let circle = match s {
                Segment::Line { circle, .. } | Segment::Arc { circle, .. } => Some(*circle),
                _ => None,
            };
            if circle.is_some_and(|c| c >= self.circles.len()) {
                return Err(format!(
                    "segment {k} refers to a circle that is not in `circles`"
                ));
            }
            if let (Some(end), Some(from)) = (at, s.from_mm()) {
                if dist(&end, &from) > 1e-9 {
                    return Err(format!(
                        "segment {k} does not start where segment {} ended",
                        k - 1
                    ));
                }
            }
            let finite = match s {
                Segment::Dwell { seconds } => seconds.is_finite() && *seconds >= 0.0,
                Segment::Arc { radius_mm, .. } => *radius_mm > 0.0 && s.length_mm().is_finite(),
                Segment::Line { feed_mm_min, .. } => {
                    *feed_mm_min > 0.0 && s.length_mm().is_finite()
                }
                _ => s.length_mm().is_finite(),
            };
            if !finite {
                return Err(format!("segment {k} has a number out of range"));
            }
            if let Some(end) = s.to_mm() {
                at = Some(end);
            }
        }
        Ok(())
    }

    /// Path length of segment `seg` (mm; 0 for a stop or a dwell).
    ///
    /// # Panics
    /// If `seg` is not an index of `segments`.
    pub fn length_mm(&self, seg: usize) -> f64 {
        self.segments[seg].length_mm()
    }

    /// The nominal position (program coordinates, mm) at path length `s_mm` along segment
    /// `seg`, `s_mm` clamped to [0, length]. An arc's point is on its nominal circle (centre,
    /// radius, angles); its ends are grid points on that circle, `from_mm` and `to_mm`, within
    /// [`ON_CIRCLE_NM`]. A stop or a dwell is where the previous motion ended.
    ///
    /// # Panics
    /// If `seg` is not an index of `segments`.
    pub fn position_at(&self, seg: usize, s_mm: f64) -> [f64; 3] {
        let segment = &self.segments[seg];
        let s = s_mm.clamp(0.0, segment.length_mm());
        match segment {
            Segment::Rapid { from_mm, to_mm } | Segment::Line { from_mm, to_mm, .. } => {
                let len = dist(from_mm, to_mm);
                let t = if len > 0.0 { s / len } else { 0.0 };
                std::array::from_fn(|k| from_mm[k] + t * (to_mm[k] - from_mm[k]))
            }
            Segment::Arc {
                centre_mm,
                radius_mm,
                plane,
                start_deg,
                sweep_deg,
                ..
            } => {
                let a = start_deg.to_radians() + sweep_deg.signum() * s / radius_mm;
                let (i, j, _) = plane.axes();
                let mut p = *centre_mm;
                p[i] += radius_mm * a.cos();
                p[j] += radius_mm * a.sin();
                p
            }
            Segment::Stop | Segment::Dwell { .. } => self.segments[..seg]
                .iter()
                .rev()
                .find_map(Segment::to_mm)
                .unwrap_or(self.start_mm),
        }
    }

    /// Smallest and largest D (mm) on segment `seg`, exact: a line's closest and farthest points
    /// to the table ball, an arc's circle (D is constant on it) and its grid-rounded ends; `None`
    /// for a stop or a dwell.
    ///
    /// # Panics
    /// If `seg` is not an index of `segments`.
    pub fn d_range_mm(&self, seg: usize) -> Option<(f64, f64)> {
        let c = &self.centre_mm;
        match &self.segments[seg] {
            Segment::Rapid { from_mm, to_mm } | Segment::Line { from_mm, to_mm, .. } => {
                Some(line_d_range(c, from_mm, to_mm))
            }
            Segment::Arc {
                from_mm,
                to_mm,
                radius_mm,
                centre_mm,
                ..
            } => {
                let d = [dist(c, from_mm), dist(c, to_mm), {
                    let h = dist(c, centre_mm);
                    (radius_mm * radius_mm + h * h).sqrt()
                }];
                Some((
                    d.iter().copied().fold(f64::INFINITY, f64::min),
                    d.iter().copied().fold(0.0, f64::max),
                ))
            }
            Segment::Stop | Segment::Dwell { .. } => None,
        }
    }

    /// Smallest and largest D (mm) over every segment after the stop: what the mounted
    /// instrument sees.
    pub fn mounted_d_range_mm(&self) -> (f64, f64) {
        (2..self.segments.len())
            .filter_map(|k| self.d_range_mm(k))
            .fold((f64::INFINITY, 0.0), |(lo, hi), (a, b)| {
                (lo.min(a), hi.max(b))
            })
    }

    /// The box the spindle ball's centre travels in (program coordinates, mm): smallest and
    /// largest x, y, z over every segment ([`Plan::segment_travel_mm`]). For checking the
    /// machine's travel and clearances.
    pub fn travel_mm(&self) -> ([f64; 3], [f64; 3]) {
        (0..self.segments.len())
            .filter_map(|k| self.segment_travel_mm(k))
            .fold(
                ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]),
                |(lo, hi), (a, b)| {
                    (
                        std::array::from_fn(|i| lo[i].min(a[i])),
                        std::array::from_fn(|i| hi[i].max(b[i])),
                    )
                },
            )
    }

    /// The box segment `seg` moves the spindle ball's centre through (program coordinates, mm):
    /// smallest and largest x, y, z, arcs sampled every 0.1 mm (within 0.1 µm of their extremes
    /// at radii above 10 mm); `None` for a stop or a dwell.
    ///
    /// # Panics
    /// If `seg` is not an index of `segments`.
    pub fn segment_travel_mm(&self, seg: usize) -> Option<([f64; 3], [f64; 3])> {
        let s = &self.segments[seg];
        s.to_mm()?;
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        let len = s.length_mm();
        let n = if matches!(s, Segment::Arc { .. }) {
            (len / 0.1).ceil().max(1.0) as usize
        } else {
            1
        };
        for m in 0..=n {
            let p = self.position_at(seg, len * m as f64 / n as f64);
            for a in 0..3 {
                lo[a] = lo[a].min(p[a]);
                hi[a] = hi[a].max(p[a]);
            }
        }
        Some((lo, hi))
    }

    /// The plan's id: 16 hex digits of a hash (FNV-1a, 64 bit) of its content, so that a record
    /// made for it (`jdbb record --plan`, `jdbb simulate --plan`; the record's `# plan_id:`
    /// line, [`PLAN_ID_KEY`]) can be told from one of another plan. The same plan read back from
    /// its plan.json has the same id.
    pub fn id(&self) -> String {
        let bytes = serde_json::to_vec(self).expect("a plan is plain data");
        let mut h: u64 = 0xcbf2_9ce4_8422_2325;
        for b in bytes {
            h ^= u64::from(b);
            h = h.wrapping_mul(0x0100_0000_01b3);
        }
        format!("{h:016x}")
    }

    /// Estimated run time (s) at the programmed feeds, without acceleration, the first rapid or
    /// the operator's stop.
    pub fn nominal_duration_s(&self) -> f64 {
        self.segments
            .iter()
            .filter_map(Segment::nominal_duration_s)
            .sum()
    }
}

/// A version-1 plan.json: a version-2 one without `arc`.
#[derive(Deserialize)]
struct PlanV1 {
    format: String,
    version: u32,
    purpose: Purpose,
    program: String,
    dialect: Dialect,
    units: String,
    plane: Plane,
    centre_mm: [f64; 3],
    feed_mm_min: f64,
    instrument: Instrument,
    start_mm: [f64; 3],
    circles: Vec<Circle>,
    segments: Vec<Segment>,
}

impl PlanV1 {
    /// The plan, with the arc of its full circles.
    fn into_plan(self) -> Plan {
        Plan {
            arc: CircleArc::of_full_circles(&self.segments),
            close: Close::None,
            format: self.format,
            version: self.version,
            purpose: self.purpose,
            program: self.program,
            dialect: self.dialect,
            units: self.units,
            plane: self.plane,
            centre_mm: self.centre_mm,
            feed_mm_min: self.feed_mm_min,
            instrument: self.instrument,
            start_mm: self.start_mm,
            circles: self.circles,
            segments: self.segments,
        }
    }
}

fn json_error(path: &Path, e: &serde_json::Error) -> Error {
    // serde_json's message ends in " at line L column C": the location goes in front instead.
    let text = e.to_string();
    let message = text
        .rsplit_once(" at line ")
        .map_or(text.as_str(), |(m, _)| m);
    Error::input(
        path,
        e.line().max(1),
        e.column(),
        format!("{message}; a plan.json is written by `jdbb plan`"),
    )
}
