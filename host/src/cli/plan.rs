//! `jdbb plan`: the program a ballbar test runs, and its plan.json ([`crate::plan`]).
use std::path::{Path, PathBuf};

use jdbb_core::calib::Calibration;

use super::output::emit;
use crate::fsio::FileSet;
use crate::plan::build::{
    DEFAULT_ARC_DEG, DEFAULT_CORNER_DWELL_S, DEFAULT_DWELL_S, DEFAULT_FEED_IN_MM,
};
use crate::plan::{
    calibration_circles, default_calibration_distances, default_lead_in_overshoot, gcode,
    instrument, machine_test_circles, plan, write_program, Close, Dialect, LineRole, Plan,
    PlanSpec, Plane, Purpose, Segment,
};
use crate::sync::MIN_CRUISE_FRACTION;
use crate::volumetric::plan as volumetric;
use crate::{Error, Result};

/// Arguments of `jdbb plan`.
#[derive(Debug, clap::Args)]
pub struct PlanArgs {
    /// The machine profile, a FILE or a machine's NAME (`crate::profile`): its controller,
    /// feeds, table ball (machine coordinates less its work offset) and travel stand where
    /// --dialect, --feed, --centre and --travel are not given.
    #[arg(long, value_name = "FILE|NAME")]
    pub machine_profile: Option<std::path::PathBuf>,
    /// Circle radius in mm (repeat for several radii: the instrument stays mounted between them).
    #[arg(long = "radius", value_name = "MM", value_parser = super::args::positive, required_unless_present_any = ["calibration_test", "volumetric"])]
    pub radii_mm: Vec<f64>,
    /// Height of a circle's plane above the table ball along the plane's normal, mm (repeat;
    /// default 0; with --volumetric the xy cones' heights, default 0, D/3 and 2D/3).
    #[arg(long = "height", value_name = "MM", allow_negative_numbers = true, value_parser = super::args::finite)]
    pub heights_mm: Vec<f64>,
    /// Plane of the circles: xy, yz or zx.
    #[arg(long, default_value = "xy", value_parser = parse_plane)]
    pub plane: Plane,
    /// Feed along the path, mm/min. Repeat for a feed sweep: the same circles again at each feed,
    /// in the order given, in one program (servo effects grow with feed, mechanical ones do not).
    #[arg(long = "feed", value_name = "MM_PER_MIN", required_unless_present = "machine_profile", value_parser = super::args::positive)]
    pub feeds_mm_min: Vec<f64>,
    /// Where the table ball's centre is, in the program's coordinates: X,Y,Z in mm.
    #[arg(long, value_name = "X,Y,Z", allow_hyphen_values = true, value_parser = parse_centre, required_unless_present = "machine_profile")]
    pub centre: Option<[f64; 3]>,
    /// Controller dialect of the program: linuxcnc, grbl, fanuc or marlin (default linuxcnc).
    #[arg(long, value_parser = parse_dialect)]
    pub dialect: Option<Dialect>,
    /// The instrument's calibration: TOML of its fields (l1_mm, l2_mm, tables enc1 and enc2).
    /// Default: the 50 mm bars of the default instrument.
    #[arg(long, value_name = "CAL.toml")]
    pub calibration: Option<PathBuf>,
    /// Plan the calibration test instead: spheres at several ball distances (see --distance).
    #[arg(long, conflicts_with_all = ["radii_mm", "heights_mm"])]
    pub calibration_test: bool,
    /// Ball distance of a sphere of the calibration test, mm (repeat; default: 4 over the range);
    /// with --volumetric of the cones and arcs (default: the middle of the range).
    #[arg(long = "distance", value_name = "MM", value_parser = super::args::positive)]
    pub distances_mm: Vec<f64>,
    /// Plan the volumetric test instead: all three axes from one mount, xy circles at each
    /// --height (cones about the table ball) and zx and yz 220° arcs through it, on each
    /// --distance; prints what the test determines.
    #[arg(long, conflicts_with_all = ["calibration_test", "radii_mm", "plane", "start_deg", "arc_deg", "lead_in_deg", "overshoot_deg"])]
    pub volumetric: bool,
    /// The machine's travel in the program's coordinates, e.g. `x=0:500,y=0:400,z=-400:0` (mm):
    /// a plan that leaves it is refused, naming the element and by how much.
    #[arg(long, value_name = "x=MIN:MAX,..")]
    pub travel: Option<String>,
    /// Angle where each circle starts and ends, degrees from the plane's first axis towards its
    /// second (xy: from x, yz: from y, zx: from z).
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true, value_parser = super::args::finite)]
    pub start_deg: f64,
    /// The arc each circle runs, degrees (above 0, at most 360): below 360 the machine stays on
    /// the arc from --start-deg over this many degrees (the vertical-plane test: --arc-deg 220
    /// --start-deg -20), runs it ccw, then back cw.
    #[arg(long, default_value_t = DEFAULT_ARC_DEG, allow_negative_numbers = true, value_parser = super::args::finite, conflicts_with = "calibration_test")]
    pub arc_deg: f64,
    /// Lead-in arc before the data arc, degrees (default 180; on a partial arc 20, taken from
    /// inside the arc).
    #[arg(long, value_parser = super::args::non_negative)]
    pub lead_in_deg: Option<f64>,
    /// Overshoot arc after the data arc, degrees (default 180; on a partial arc 20, taken from
    /// inside the arc).
    #[arg(long, value_parser = super::args::non_negative)]
    pub overshoot_deg: Option<f64>,
    /// Length of the radial feed-in onto each circle (and feed-out), mm.
    #[arg(long, default_value_t = DEFAULT_FEED_IN_MM, value_parser = super::args::positive)]
    pub feed_in_mm: f64,
    /// Dwell before each feed-in and after each feed-out, s (0: none).
    #[arg(long, default_value_t = DEFAULT_DWELL_S, value_parser = super::args::non_negative)]
    pub dwell_s: f64,
    /// Dwell at each reversal, s (default: --dwell-s; 0: none).
    #[arg(long, value_parser = super::args::non_negative)]
    pub reversal_dwell_s: Option<f64>,
    /// Dwell at the corner after each feed-in and before each feed-out, s (0: none; then grbl
    /// and Marlin pass the corner at their junction speed instead of stopping).
    #[arg(long, default_value_t = DEFAULT_CORNER_DWELL_S, value_parser = super::args::non_negative)]
    pub corner_dwell_s: f64,
    /// Close the test on itself in time: `first` runs the first circle again at the end, `abba`
    /// the circles in order and then in reverse; `none` runs each once. Heat grows an axis during
    /// the test: a closed test tells that growth (`scale_drift_k`) from the scale.
    #[arg(long, value_enum, default_value_t = Close::None)]
    pub close: Close,
    /// Directory for plan.json and the program (created if missing); both are written as a set
    /// (both new, or both as they were).
    #[arg(long, short, value_name = "DIR")]
    pub out: PathBuf,
    /// Replace a plan.json or program already in --out (a recorded test may refer to it).
    #[arg(long)]
    pub force: bool,
}

fn parse_plane(s: &str) -> std::result::Result<Plane, String> {
    Plane::parse(s).ok_or_else(|| format!("`{s}`: use xy, yz or zx"))
}

fn parse_dialect(s: &str) -> std::result::Result<Dialect, String> {
    Dialect::parse(s).ok_or_else(|| {
        let names: Vec<&str> = Dialect::ALL.iter().map(|d| d.name()).collect();
        format!("`{s}`: use {}", names.join(", "))
    })
}

/// `X,Y,Z` in mm: three finite numbers.
fn parse_centre(s: &str) -> std::result::Result<[f64; 3], String> {
    let parts: Vec<&str> = s.split(',').collect();
    if parts.len() != 3 {
        return Err(format!(
            "`{s}`: give the table ball's centre as three numbers X,Y,Z in mm, e.g. 100,50,-20"
        ));
    }
    let mut p = [0.0; 3];
    for (k, part) in parts.iter().enumerate() {
        p[k] = super::args::finite(part)
            .map_err(|e| format!("`{s}`: {} is {e}", ["X", "Y", "Z"][k]))?;
    }
    Ok(p)
}

/// The program's dialect for the profile's `controller` (as `compensate --controller` names it),
/// where `jdbb plan` writes one.
fn profile_dialect(controller: &str) -> Result<Dialect> {
    let c = crate::compensate::Controller::parse(controller)?;
    use crate::compensate::Controller as C;
    match c {
        C::LinuxCnc => Ok(Dialect::Linuxcnc),
        C::GrblHal => Ok(Dialect::Grbl),
        C::Fanuc => Ok(Dialect::Fanuc),
        C::Marlin => Ok(Dialect::Marlin),
        _ => Err(Error::Usage(format!(
            "the machine profile's controller {} has no program dialect in jdbb plan: give --dialect (linuxcnc, grbl, fanuc or marlin)",
            c.name()
        ))),
    }
}

/// What `jdbb plan` takes from the machine profile where its flags are not given: dialect,
/// feeds, the table ball's centre and the travel, all in the program's coordinates.
struct FromProfile {
    dialect: Dialect,
    feeds_mm_min: Vec<f64>,
    centre_mm: [f64; 3],
    travel: Option<[Option<(f64, f64)>; 3]>,
    /// Where the centre came from, when the profile gave it: a line of the printout.
    centre_note: Option<String>,
}

/// The plan's dialect, feeds, centre and travel: each flag given, else the profile's value.
fn from_profile(args: &PlanArgs) -> Result<FromProfile> {
    let profile = match &args.machine_profile {
        Some(f) => crate::profile::MachineProfile::find(f)?,
        None => crate::profile::MachineProfile::default(),
    };
    let dialect = match (args.dialect, &profile.controller) {
        (Some(d), _) => d,
        (None, Some(c)) => profile_dialect(c)?,
        (None, None) => Dialect::Linuxcnc,
    };
    let feeds_mm_min = if args.feeds_mm_min.is_empty() {
        profile.feeds_mm_min.clone()
    } else {
        args.feeds_mm_min.clone()
    };
    if feeds_mm_min.is_empty() {
        return Err(Error::Usage(
            "give --feed MM_PER_MIN, or a machine profile with feeds_mm_min".into(),
        ));
    }
    let mut centre_note = None;
    let centre_mm = match (args.centre, profile.centre_mm()?) {
        (Some(c), _) => c,
        (None, Some(c)) => {
            let offset: [f64; 3] = std::array::from_fn(|a| profile.work_offset(a));
            centre_note = Some(format!(
                "table ball from the machine profile: machine (G53) {} less the work offset {} (run the program with that work offset in force)\n",
                point(&std::array::from_fn(|a| c[a] + offset[a])),
                point(&offset)
            ));
            c
        }
        (None, None) => {
            return Err(Error::Usage(
                "give --centre X,Y,Z, or a machine profile with table_ball_mm".into(),
            ))
        }
    };
    let travel = match &args.travel {
        Some(t) => Some(super::args::travel_mm("--travel", t)?),
        None => (!profile.travel_mm.is_empty()).then(|| profile.travel_program_mm()),
    };
    Ok(FromProfile {
        dialect,
        feeds_mm_min,
        centre_mm,
        travel,
        centre_note,
    })
}

/// Run `jdbb plan`.
pub fn run(args: &PlanArgs) -> Result<()> {
    let given = from_profile(args)?;
    let cal = match &args.calibration {
        Some(path) => crate::instrument::file::read_calibration(path)?,
        None => Calibration::DEFAULT,
    };
    let inst = instrument(&cal)?;
    if !args.distances_mm.is_empty() && !args.calibration_test && !args.volumetric {
        return Err(Error::Usage(
            "--distance is the ball distance of --calibration-test or --volumetric; a machine test takes --radius and --height".into(),
        ));
    }
    let heights_mm = if args.heights_mm.is_empty() && !args.volumetric {
        vec![0.0]
    } else {
        args.heights_mm.clone()
    };
    let (purpose, circles) = if args.calibration_test {
        let d = if args.distances_mm.is_empty() {
            default_calibration_distances(&inst, args.feed_in_mm)
        } else {
            args.distances_mm.clone()
        };
        (Purpose::CalibrationTest, calibration_circles(&d))
    } else {
        (
            Purpose::MachineTest,
            machine_test_circles(&args.radii_mm, &heights_mm),
        )
    };
    let (lead_in_deg, overshoot_deg) = default_lead_in_overshoot(args.arc_deg);
    let spec = PlanSpec {
        purpose,
        circles,
        plane: args.plane,
        feed_mm_min: given.feeds_mm_min[0],
        centre_mm: given.centre_mm,
        dialect: given.dialect,
        start_deg: args.start_deg,
        arc_deg: args.arc_deg,
        lead_in_deg: args.lead_in_deg.unwrap_or(lead_in_deg),
        overshoot_deg: args.overshoot_deg.unwrap_or(overshoot_deg),
        feed_in_mm: args.feed_in_mm,
        dwell_s: args.dwell_s,
        reversal_dwell_s: args.reversal_dwell_s.unwrap_or(args.dwell_s),
        corner_dwell_s: args.corner_dwell_s,
        close: args.close,
    }
    .feed_sweep(&given.feeds_mm_min);
    let plan = if args.volumetric {
        let distances_mm = if args.distances_mm.is_empty() {
            vec![volumetric::default_distance_mm(&inst)]
        } else {
            args.distances_mm.clone()
        };
        volumetric::plan(
            &volumetric::VolumetricSpec {
                distances_mm,
                heights_mm,
                base: spec,
            },
            &cal,
        )?
    } else {
        plan(&spec, &cal)?
    };
    if let Some(travel) = &given.travel {
        volumetric::check_travel(&plan, travel)?;
    }
    let program = write_program(&plan, given.dialect);
    let json_path = args.out.join("plan.json");
    let program_path = args.out.join(&plan.program);
    // plan.json and its program are one set: both new, or both as they were.
    let mut set = FileSet::new(&args.out, args.force)?;
    let inputs: Vec<(&str, &Path)> = args
        .calibration
        .iter()
        .map(|c| ("--calibration", c.as_path()))
        .collect();
    set.check(&["plan.json", &plan.program], &inputs)
        .map_err(|e| match e {
        Error::OutputExists { path } => Error::Usage(format!(
            "{} exists, and a recorded test may refer to it: choose another --out, or add --force to replace it",
            path.display()
        )),
        e => e,
    })?;
    set.add("plan.json", plan.to_json().as_bytes())?;
    set.add(&plan.program, program.as_bytes())?;
    // The program of the plan replaced, if of another dialect, goes with it: a folder holds one
    // plan and its program, never a stale program beside a new plan.json.
    if let Some(old) = old_program(&json_path).filter(|p| *p != plan.program) {
        set.remove(old);
    }
    set.commit()?;
    let blocks = program.lines().count();
    emit(
        &(given.centre_note.unwrap_or_default()
            + &if args.volumetric {
                super::volumetric::setup_text(&plan, &json_path, &program_path, blocks)
            } else {
                setup_text(&plan, &json_path, &program_path, blocks)
            }),
    )
}

/// The program named by the plan at `json` (a plan.json jdbb wrote), if it is one of jdbb's
/// program names: only a program jdbb writes is ever removed with the plan it belongs to.
fn old_program(json: &Path) -> Option<&'static str> {
    if !json.is_file() {
        return None;
    }
    let text = crate::table::read_text(json).ok()?;
    let v: serde_json::Value = serde_json::from_str(&text).ok()?;
    let name = v.get("program")?.as_str()?;
    Dialect::ALL
        .iter()
        .map(|d| d.program_name())
        .find(|p| *p == name)
}

fn point(p: &[f64; 3]) -> String {
    format!("X {:.3}  Y {:.3}  Z {:.3} mm", p[0], p[1], p[2])
}

fn duration(s: f64) -> String {
    let s = s.round() as u64;
    if s >= 60 {
        format!("{} min {} s", s / 60, s % 60)
    } else {
        format!("{s} s")
    }
}

/// The ball distances a plan uses (on its `elements`, feed-ins and moves) and the box the
/// spindle ball travels in: two lines of the printout.
pub(super) fn reach_text(plan: &Plan, elements: &str) -> String {
    let (lo, hi) = plan.mounted_d_range_mm();
    let mut t =
        format!("ball distances used: {lo:.3}..{hi:.3} mm ({elements}, feed-ins and moves)\n");
    let (lo, hi) = plan.travel_mm();
    t += &format!(
        "spindle ball travel: X {:.3}..{:.3}  Y {:.3}..{:.3}  Z {:.3}..{:.3} mm\n",
        lo[0], hi[0], lo[1], hi[1], lo[2], hi[2]
    );
    t
}

/// Where the table ball goes, where the program stops for the operator to mount the instrument
/// (`mounted`: what to add about it) and the instrument's range: three lines of the printout.
pub(super) fn place_text(plan: &Plan, mounted: &str) -> String {
    format!(
        "table ball centre:   {}\nstart point:         {}  (the program stops here: mount the instrument, then cycle start{mounted})\ninstrument range:    D {}\n",
        point(&plan.centre_mm),
        point(&plan.start_mm),
        plan.instrument.describe()
    )
}

/// The files written and the estimated run time: the printout's last two lines.
pub(super) fn written_text(plan: &Plan, json: &Path, program: &Path, blocks: usize) -> String {
    format!(
        "wrote {} and {} ({blocks} lines)\nestimated run time:  {} at the programmed feed (without the rapid, the stop and acceleration)",
        json.display(),
        program.display(),
        duration(plan.nominal_duration_s())
    )
}

/// A slow machine's acceleration (mm/s²), for the feed-in a partial arc needs.
const SLOW_ACCEL_MM_S2: f64 = 300.0;

/// What the operator needs: where the table ball goes, where to mount, the distances used.
fn setup_text(plan: &Plan, json: &Path, program: &Path, blocks: usize) -> String {
    let inst = &plan.instrument;
    let mut t = format!(
        "{} in plane {}, {} circle(s), each ccw then cw at {} mm/min ({})\n",
        match plan.purpose {
            Purpose::MachineTest => "machine test",
            Purpose::CalibrationTest => "calibration test (spheres at several ball distances)",
            Purpose::VolumetricTest => "volumetric test",
        },
        plan.plane.name(),
        plan.circles.len(),
        plan.feeds_mm_min()
            .into_iter()
            .map(gcode::number)
            .collect::<Vec<_>>()
            .join(", "),
        plan.dialect.name()
    );
    let arc = &plan.arc;
    if arc.is_partial() {
        // Degrees to the millidegree, without trailing zeros (220, -20, 37.5).
        let deg = |x: f64| {
            let r = (x * 1000.0).round() / 1000.0;
            if r == 0.0 {
                0.0
            } else {
                r
            }
        };
        t += &format!(
            "arc:                 {}° from {}° to {}° of the plane's first axis ({}), not beyond: lead-in {}°, data {}° to {}°, overshoot {}°, each way\n",
            deg(arc.sweep_deg),
            deg(arc.start_deg),
            deg(arc.start_deg + arc.sweep_deg),
            ["x", "y", "z"][plan.plane.axes().0],
            deg(arc.lead_in_deg),
            deg(arc.data_start_deg),
            deg(arc.data_start_deg + arc.data_sweep_deg),
            deg(arc.overshoot_deg),
        );
    }
    t += &place_text(plan, "");
    t += "circles:\n";
    for c in &plan.circles {
        let phi = inst
            .deflection_deg(c.d_mm)
            .map_or(String::new(), |p| format!(", deflection {p:.1}°"));
        t += &format!(
            "  {:>2}  R {:>8.3} mm  H {:>8.3} mm  D {:>8.3} mm{phi}\n",
            c.index + 1,
            c.radius_mm,
            c.height_mm,
            c.d_mm
        );
    }
    t += &reach_text(plan, "circles");
    let (lo, _) = plan.travel_mm();
    let below_mm = plan.centre_mm[2] - lo[2];
    if plan.plane != Plane::Xy && !arc.is_partial() {
        t += &format!(
            "note: in plane {} half of each circle passes below the table ball's centre (Z {:.3}): the table ball must stand high enough for the spindle to get there\n",
            plan.plane.name(),
            lo[2]
        );
    } else if plan.plane != Plane::Xy && below_mm > 1e-3 {
        t += &format!(
            "note: the arc passes {below_mm:.3} mm below the table ball's centre (Z {:.3}): the table ball must stand high enough for the spindle to get there\n",
            lo[2]
        );
        if plan.plane == Plane::Zx {
            t += "note: in plane zx angles run from z towards x; the arc that stays above the table from -20° to 200° of x is --start-deg -110\n";
        }
    }
    if arc.is_partial() {
        // The synchronisation takes a partial arc's feed from the feed-in's cruise
        // (`sync`): the feed-in must be long enough to reach the feed.
        let fastest_mm_min = plan
            .circles
            .iter()
            .map(|c| c.feed_mm_min)
            .fold(plan.feed_mm_min, f64::max);
        let v = fastest_mm_min / 60.0;
        let need = v * v / SLOW_ACCEL_MM_S2 / (1.0 - MIN_CRUISE_FRACTION);
        let feed_in = plan
            .segments
            .iter()
            .find(|s| {
                matches!(
                    s,
                    Segment::Line {
                        role: LineRole::FeedIn,
                        ..
                    }
                )
            })
            .map_or(0.0, Segment::length_mm);
        if feed_in < need {
            t += &format!(
                "note: on a partial arc the feed is measured on the feed-in, which must reach it: at {} mm/min a machine accelerating at {SLOW_ACCEL_MM_S2} mm/s² needs a feed-in of {:.1} mm or more (--feed-in-mm), this one is {feed_in:.1} mm\n",
                gcode::number(fastest_mm_min),
                (need * 10.0).ceil() / 10.0
            );
        }
    }
    if plan.dialect == Dialect::Marlin && plan.plane != Plane::Xy {
        t += "note: Marlin selects G18/G19 only with CNC_WORKSPACE_PLANES; without it these arcs run in XY\n";
    }
    t + &written_text(plan, json, program, blocks)
}
