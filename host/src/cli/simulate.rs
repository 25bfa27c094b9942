//! `jdbb simulate`: a circular test on a machine with chosen errors, written as the
//! `t_s,x_mm,y_mm,z_mm,d_mm` CSV that `jdbb diagnose` reads.
use std::io::Write;
use std::path::PathBuf;

use super::output::stdout_result;
use crate::circular::model::{parse_pitch, Path};
use crate::circular::simulate::{
    distances_mm, measure, nominal_path, parse_effect, parse_plane, write_csv, EffectValue,
    PathSpec,
};
use crate::fsio::{check_destination, Staged};
use crate::{Error, Result};

/// Arguments of `jdbb simulate`.
#[derive(Debug, clap::Args)]
pub struct SimulateArgs {
    /// Circle radius in mm (repeat for several radii: the J-DBB's bar length is free).
    #[arg(long = "radius", default_value = "50", value_parser = super::args::positive)]
    pub radii_mm: Vec<f64>,
    /// Height of the circle's plane above the table ball, mm (repeat for several heights).
    #[arg(long = "height", default_value = "0", allow_negative_numbers = true, value_parser = super::args::finite)]
    pub heights_mm: Vec<f64>,
    /// Plane of the circles: xy, yz or zx.
    #[arg(long, default_value = "xy")]
    pub plane: String,
    /// Feed along the circle, mm/min.
    #[arg(long, default_value_t = 1000.0, value_parser = super::args::positive)]
    pub feed: f64,
    /// Sample rate, Hz.
    #[arg(long, default_value_t = 500.0, value_parser = super::args::positive)]
    pub rate: f64,
    /// A machine effect, `name=value[@phase_deg]` or `name=p1,p2,..`; repeat. Names as in
    /// `jdbb diagnose` (scale_x, backlash_y, cyclic_x, servo_mismatch_xy, setup_offset, ...).
    #[arg(long = "effect")]
    pub effects: Vec<String>,
    /// Pitch per axis in mm (x=10,y=10), needed by cyclic_k and interference_k.
    #[arg(long)]
    pub pitch: Option<String>,
    /// Gaussian reading noise, µm (1 σ).
    #[arg(long, default_value_t = 0.0, value_parser = super::args::non_negative)]
    pub sigma_um: f64,
    /// Reading resolution, µm (D is rounded to it; 0 = none).
    #[arg(long, default_value_t = 0.0, value_parser = super::args::non_negative)]
    pub resolution_um: f64,
    /// Seed of the noise.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Output CSV (stdout if absent); written whole or not at all.
    #[arg(long, short)]
    pub out: Option<PathBuf>,
    /// Replace --out if it exists (a regular file only; never a link or a device).
    #[arg(long, requires = "out")]
    pub force: bool,
}

/// Run `jdbb simulate`.
pub fn run(args: &SimulateArgs) -> Result<()> {
    if let Some(file) = &args.out {
        // Before the work: a destination that will be refused is refused at once.
        check_destination(file, args.force)?;
    }
    let spec = PathSpec {
        radii_mm: args.radii_mm.clone(),
        heights_mm: args.heights_mm.clone(),
        plane: parse_plane(&args.plane)?,
        feed_mm_min: args.feed,
        rate_hz: args.rate,
    };
    spec.validate()?;
    let pitch = match &args.pitch {
        Some(s) => parse_pitch(s)?,
        None => [None; 3],
    };
    let effects: Vec<EffectValue> = args
        .effects
        .iter()
        .map(|s| parse_effect(s))
        .collect::<Result<_>>()?;
    let (t, p) = nominal_path(&spec);
    let path = Path::new(t, p, pitch);
    let mut d = distances_mm(&path, &effects)?;
    measure(&mut d, args.sigma_um, args.resolution_um, args.seed);
    match &args.out {
        Some(file) => {
            let mut w = Staged::create(file, args.force)?;
            write_csv(&mut w, &path, &d).map_err(|source| Error::File {
                action: "cannot write",
                path: file.clone(),
                source,
            })?;
            w.commit()
        }
        None => {
            let mut w = std::io::BufWriter::new(std::io::stdout().lock());
            stdout_result(write_csv(&mut w, &path, &d).and_then(|_| w.flush()))
        }
    }
}
