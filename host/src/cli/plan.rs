//! `jdbb plan`: the program a ballbar test runs, and its plan.json ([`crate::circular::plan`]).
use std::path::{Path, PathBuf};

use jdbb_core::calib::Calibration;

use super::output::emit;
use crate::circular::plan::build::{
    DEFAULT_CORNER_DWELL_S, DEFAULT_DWELL_S, DEFAULT_FEED_IN_MM, DEFAULT_LEAD_IN_DEG,
    DEFAULT_OVERSHOOT_DEG,
};
use crate::circular::plan::{
    calibration_circles, default_calibration_distances, gcode, instrument, machine_test_circles,
    plan, write_program, Dialect, Plan, PlanSpec, Plane, Purpose,
};
use crate::fsio::FileSet;
use crate::{Error, Result};

/// Arguments of `jdbb plan`.
#[derive(Debug, clap::Args)]
pub struct PlanArgs {
    /// Circle radius in mm (repeat for several radii: the instrument stays mounted between them).
    #[arg(long = "radius", value_name = "MM", value_parser = super::args::positive, required_unless_present = "calibration_test")]
    pub radii_mm: Vec<f64>,
    /// Height of a circle's plane above the table ball along the plane's normal, mm (repeat).
    #[arg(long = "height", value_name = "MM", default_value = "0", allow_negative_numbers = true, value_parser = super::args::finite)]
    pub heights_mm: Vec<f64>,
    /// Plane of the circles: xy, yz or zx.
    #[arg(long, default_value = "xy", value_parser = parse_plane)]
    pub plane: Plane,
    /// Feed along the path, mm/min.
    #[arg(long, value_name = "MM_PER_MIN", value_parser = super::args::positive)]
    pub feed: f64,
    /// Where the table ball's centre is, in the program's coordinates: X,Y,Z in mm.
    #[arg(long, value_name = "X,Y,Z", allow_hyphen_values = true, value_parser = parse_centre)]
    pub centre: [f64; 3],
    /// Controller dialect of the program: linuxcnc, grbl, fanuc or marlin.
    #[arg(long, default_value = "linuxcnc", value_parser = parse_dialect)]
    pub dialect: Dialect,
    /// The instrument's calibration: TOML of its fields (l1_mm, l2_mm, tables enc1 and enc2).
    /// Default: the 50 mm bars of the default instrument.
    #[arg(long, value_name = "CAL.toml")]
    pub calibration: Option<PathBuf>,
    /// Plan the calibration test instead: spheres at several ball distances (see --distance).
    #[arg(long, conflicts_with_all = ["radii_mm", "heights_mm"])]
    pub calibration_test: bool,
    /// Ball distance of a sphere of the calibration test, mm (repeat; default: 4 over the range).
    #[arg(long = "distance", value_name = "MM", requires = "calibration_test", value_parser = super::args::positive)]
    pub distances_mm: Vec<f64>,
    /// Angle where each circle starts and ends, degrees from the plane's first axis.
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true, value_parser = super::args::finite)]
    pub start_deg: f64,
    /// Lead-in arc before the 360° of data, degrees.
    #[arg(long, default_value_t = DEFAULT_LEAD_IN_DEG, value_parser = super::args::non_negative)]
    pub lead_in_deg: f64,
    /// Overshoot arc after the 360° of data, degrees.
    #[arg(long, default_value_t = DEFAULT_OVERSHOOT_DEG, value_parser = super::args::non_negative)]
    pub overshoot_deg: f64,
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

/// Run `jdbb plan`.
pub fn run(args: &PlanArgs) -> Result<()> {
    let cal = match &args.calibration {
        Some(path) => crate::instrument::file::read_calibration(path)?,
        None => Calibration::DEFAULT,
    };
    let inst = instrument(&cal)?;
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
            machine_test_circles(&args.radii_mm, &args.heights_mm),
        )
    };
    let spec = PlanSpec {
        purpose,
        circles,
        plane: args.plane,
        feed_mm_min: args.feed,
        centre_mm: args.centre,
        dialect: args.dialect,
        start_deg: args.start_deg,
        lead_in_deg: args.lead_in_deg,
        overshoot_deg: args.overshoot_deg,
        feed_in_mm: args.feed_in_mm,
        dwell_s: args.dwell_s,
        reversal_dwell_s: args.reversal_dwell_s.unwrap_or(args.dwell_s),
        corner_dwell_s: args.corner_dwell_s,
    };
    let plan = plan(&spec, &cal)?;
    let program = write_program(&plan, args.dialect);
    let json_path = args.out.join("plan.json");
    let program_path = args.out.join(&plan.program);
    // plan.json and its program are one set: both new, or both as they were.
    let mut set = FileSet::new(&args.out, args.force)?;
    set.check(&["plan.json", &plan.program]).map_err(|e| match e {
        Error::OutputExists { path } => Error::Usage(format!(
            "{} exists, and a recorded test may refer to it: choose another --out, or add --force to replace it",
            path.display()
        )),
        e => e,
    })?;
    set.add("plan.json", plan.to_json().as_bytes())?;
    set.add(&plan.program, program.as_bytes())?;
    set.commit()?;
    emit(&setup_text(
        &plan,
        &json_path,
        &program_path,
        program.lines().count(),
    ))
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

/// What the operator needs: where the table ball goes, where to mount, the distances used.
fn setup_text(plan: &Plan, json: &Path, program: &Path, blocks: usize) -> String {
    let inst = &plan.instrument;
    let mut t = format!(
        "{} in plane {}, {} circle(s), each ccw then cw at {} mm/min ({})\n",
        match plan.purpose {
            Purpose::MachineTest => "machine test",
            Purpose::CalibrationTest => "calibration test (spheres at several ball distances)",
        },
        plan.plane.name(),
        plan.circles.len(),
        gcode::number(plan.feed_mm_min),
        plan.dialect.name()
    );
    t += &format!("table ball centre:   {}\n", point(&plan.centre_mm));
    t += &format!(
        "start point:         {}  (the program stops here: mount the instrument, then cycle start)\n",
        point(&plan.start_mm)
    );
    t += &format!("instrument range:    D {}\n", inst.describe());
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
    let (lo, hi) = plan.mounted_d_range_mm();
    t += &format!("ball distances used: {lo:.3}..{hi:.3} mm (circles, feed-ins and moves)\n");
    let (lo, hi) = plan.travel_mm();
    t += &format!(
        "spindle ball travel: X {:.3}..{:.3}  Y {:.3}..{:.3}  Z {:.3}..{:.3} mm\n",
        lo[0], hi[0], lo[1], hi[1], lo[2], hi[2]
    );
    if plan.plane != Plane::Xy {
        t += &format!(
            "note: in plane {} half of each circle passes below the table ball's centre (Z {:.3}): the table ball must stand high enough for the spindle to get there\n",
            plan.plane.name(),
            lo[2]
        );
    }
    if plan.dialect == Dialect::Marlin && plan.plane != Plane::Xy {
        t += "note: Marlin selects G18/G19 only with CNC_WORKSPACE_PLANES; without it these arcs run in XY\n";
    }
    t += &format!(
        "wrote {} and {} ({blocks} lines)\n",
        json.display(),
        program.display()
    );
    t += &format!(
        "estimated run time:  {} at the programmed feed (without the rapid, the stop and acceleration)",
        duration(plan.nominal_duration_s())
    );
    t
}
