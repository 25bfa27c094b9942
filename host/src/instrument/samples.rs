//! Calibration samples: CAL.csv with the columns `enc1,enc2,d_ref_mm` (any order, extra columns
//! ignored, through [`crate::table`]): the two encoders' extended counts and the reference ball
//! distance a calibrator gives at that pose (mm), e.g. a bar of CMM-measured length while the
//! knee is swung through its range.
//!
//! What a fit cannot use is refused here as bad input, naming `file:line:column`: counts that are
//! not integers, a reference that is not a positive number, too few samples, and (against the
//! nominal instrument, [`CalSamples::check_against`]) counts beyond the frames' range or a
//! reference the nominal instrument misses by more than an instrument error can make.
use std::path::{Path, PathBuf};

use jdbb_core::calib::Calibration;
use jdbb_core::geometry::{Model, KERNEL_RANGE_RAD};

use crate::table::Table;
use crate::{Error, Result};

/// Fewer samples than this cannot carry a search over the instrument's effects.
pub const MIN_SAMPLES: usize = 30;

/// Largest |d_ref − D of the nominal instrument| (mm) accepted: the instrument's errors are
/// bounded ([`jdbb_core::calib::MAX_ERROR_RAD`] on each angle, ≈ 1 mm on D at 100 mm); more is a
/// wrong column, a wrong `--nominal` or counts of another instrument.
pub const MAX_MISS_MM: f64 = 1.0;

/// The samples of one CAL.csv, with each one's line for messages.
#[derive(Debug, Clone, PartialEq)]
pub struct CalSamples {
    /// The file they came from (for messages).
    pub path: PathBuf,
    /// Encoder 1's extended counts.
    pub enc1: Vec<i64>,
    /// Encoder 2's extended counts.
    pub enc2: Vec<i64>,
    /// Reference ball distances (mm).
    pub d_ref_mm: Vec<f64>,
    /// 1-based line of each sample.
    pub line: Vec<usize>,
    /// Without a calibrator (`--record` with `--plan`): each sample's nominal ball position
    /// relative to the table ball (mm). The reference is then |p + c| with the table ball's
    /// set-up offset c fitted alongside the instrument, and `d_ref_mm` holds |p|.
    pub positions: Option<Vec<[f64; 3]>>,
    /// 1-based character column of each row's `enc1` and `d_ref_mm` fields.
    columns: Vec<[usize; 2]>,
}

impl CalSamples {
    /// Number of samples.
    pub fn len(&self) -> usize {
        self.d_ref_mm.len()
    }

    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.d_ref_mm.is_empty()
    }

    /// Samples from memory (tests, benches); `path` names them in messages, lines count from 2.
    pub fn from_vecs(path: &Path, enc1: Vec<i64>, enc2: Vec<i64>, d_ref_mm: Vec<f64>) -> Self {
        let n = d_ref_mm.len();
        CalSamples {
            path: path.to_path_buf(),
            enc1,
            enc2,
            d_ref_mm,
            line: (2..n + 2).collect(),
            positions: None,
            columns: vec![[1, 1]; n],
        }
    }

    /// Samples of a machine run (no calibrator): counts, nominal positions p relative to the
    /// table ball (mm) and each one's line in the record; the reference is |p + c| (field
    /// `positions`).
    pub fn from_positions(
        path: &Path,
        enc1: Vec<i64>,
        enc2: Vec<i64>,
        positions: Vec<[f64; 3]>,
        line: Vec<usize>,
    ) -> Self {
        let n = positions.len();
        let d_ref_mm = positions
            .iter()
            .map(|p| (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt())
            .collect();
        CalSamples {
            path: path.to_path_buf(),
            enc1,
            enc2,
            d_ref_mm,
            line,
            positions: Some(positions),
            columns: vec![[1, 1]; n],
        }
    }

    /// Refuse samples the nominal instrument cannot have made (module docs): a frame angle
    /// beyond the on-chip model's range (±86°), or a reference length the nominal instrument
    /// misses by more than [`MAX_MISS_MM`].
    pub fn check_against(&self, nominal: &Calibration) -> Result<()> {
        let model = Model::new(nominal);
        for i in 0..self.len() {
            let (t1, t2) = model.frame_angles_rad(self.enc1[i], self.enc2[i]);
            let at = |k: usize, msg: String| {
                Error::input(&self.path, self.line[i], self.columns[i][k], msg)
            };
            for (name, t) in [("enc1", t1), ("enc2", t2)] {
                if t.is_nan() || t.abs() > KERNEL_RANGE_RAD {
                    return Err(at(
                        0,
                        format!(
                            "{name} is {:.1}° from the encoder's zero, but the frames turn at most ±75°; are the counts referenced to the zero, and is counts_per_rev of the nominal calibration ({}) right?",
                            t.to_degrees(),
                            if name == "enc1" { nominal.enc1.counts_per_rev } else { nominal.enc2.counts_per_rev }
                        ),
                    ));
                }
            }
            let d = model.distance_mm(self.enc1[i], self.enc2[i]);
            let miss = self.d_ref_mm[i] - d;
            // A machine run's reference |p| also misses by the set-up offset (≤ MAX_MISS_MM).
            let limit = if self.positions.is_some() { 2.0 } else { 1.0 } * MAX_MISS_MM;
            if miss.is_nan() || miss.abs() > limit {
                return Err(at(
                    1,
                    format!(
                        "d_ref_mm is {} mm but the nominal instrument reads {d:.4} mm at these counts; an instrument error moves D by micrometres, not {:.3} mm: check the column, the bar lengths of --nominal and that the counts belong to this instrument",
                        self.d_ref_mm[i],
                        miss
                    ),
                ));
            }
        }
        Ok(())
    }
}

/// Read CAL.csv (module docs).
pub fn read_samples(file: &Path) -> Result<CalSamples> {
    samples_from(Table::open_with(file, crate::fsio::Limit::Table)?)
}

/// [`read_samples`] on text already in memory; `file` names it in errors.
pub fn parse_samples(file: &Path, text: &str) -> Result<CalSamples> {
    samples_from(Table::from_text(file, text)?)
}

fn samples_from(mut table: Table) -> Result<CalSamples> {
    let cols = table.require(&["enc1", "enc2", "d_ref_mm"])?;
    let mut s = CalSamples {
        path: table.path().to_path_buf(),
        enc1: vec![],
        enc2: vec![],
        d_ref_mm: vec![],
        line: vec![],
        positions: None,
        columns: vec![],
    };
    let mut last_line = table.header_line();
    while let Some(row) = table.next_row()? {
        last_line = row.line();
        let e1 = row.integer(&cols[0])?;
        let e2 = row.integer(&cols[1])?;
        let d = row.number(&cols[2])?;
        if d <= 0.0 {
            return Err(row.error(
                &cols[2],
                format!("d_ref_mm is {d}; a ball distance is positive (mm)"),
            ));
        }
        s.enc1.push(e1);
        s.enc2.push(e2);
        s.d_ref_mm.push(d);
        s.line.push(row.line());
        s.columns
            .push([row.column_of(cols[0].index), row.column_of(cols[2].index)]);
    }
    if s.len() < MIN_SAMPLES {
        return Err(Error::input(
            &s.path,
            last_line,
            0,
            format!(
                "only {} samples; a calibration needs at least {MIN_SAMPLES}, better a few hundred: several reference lengths, the knee swung all round at each",
                s.len()
            ),
        ));
    }
    Ok(s)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rows(n: usize) -> String {
        let mut t = String::from("enc1,enc2,d_ref_mm\n");
        for i in 0..n {
            t.push_str(&format!("{},{},{}\n", 1000 * i, -500 * (i as i64), 99.9));
        }
        t
    }

    #[test]
    fn reads_columns_in_any_order() {
        let mut text = String::from("# calibrator run\nd_ref_mm, enc2,enc1,note\n");
        for i in 0..MIN_SAMPLES {
            text.push_str(&format!("99.5,{},{},x\n", -(i as i64), i));
        }
        let s = parse_samples(Path::new("cal.csv"), &text).unwrap();
        assert_eq!(s.len(), MIN_SAMPLES);
        assert_eq!(
            (s.enc1[3], s.enc2[3], s.d_ref_mm[3], s.line[3]),
            (3, -3, 99.5, 6)
        );
    }

    #[test]
    fn bad_input_names_file_line_and_column() {
        let p = Path::new("cal.csv");
        let e = parse_samples(p, "enc1,enc2\n1,2\n").unwrap_err();
        assert!(
            e.to_string()
                .starts_with("cal.csv:1: missing column `d_ref_mm`"),
            "{e}"
        );
        let e = parse_samples(p, "enc1,enc2,d_ref_mm\n1,2.5,99\n").unwrap_err();
        assert_eq!(e.to_string(), "cal.csv:2:3: enc2: `2.5` is not an integer");
        let e = parse_samples(p, "enc1,enc2,d_ref_mm\n1,2,-3\n").unwrap_err();
        assert!(
            e.to_string().starts_with("cal.csv:2:5: d_ref_mm is -3"),
            "{e}"
        );
        let e = parse_samples(p, &rows(5)).unwrap_err();
        assert!(
            e.to_string().starts_with("cal.csv:6: only 5 samples"),
            "{e}"
        );
        assert_eq!(e.exit_code(), 2);
    }

    #[test]
    fn samples_the_nominal_instrument_cannot_make_are_refused() {
        let p = Path::new("cal.csv");
        let nominal = Calibration::DEFAULT;
        // Counts at 90° and 100 mm: beyond the frames.
        let mut text = rows(MIN_SAMPLES);
        text.push_str(&format!("{},0,99\n", 1 << 21));
        let s = parse_samples(p, &text).unwrap();
        let e = s.check_against(&nominal).unwrap_err();
        assert!(
            e.to_string()
                .starts_with(&format!("cal.csv:{}:1: enc1 is 90.0°", MIN_SAMPLES + 2)),
            "{e}"
        );
        // At the zero the nominal instrument reads 100 mm; a 90 mm reference is no instrument error.
        let mut text = String::from("enc1,enc2,d_ref_mm\n");
        for _ in 0..MIN_SAMPLES {
            text.push_str("0,0,90\n");
        }
        let e = parse_samples(p, &text)
            .unwrap()
            .check_against(&nominal)
            .unwrap_err();
        assert!(
            e.to_string().starts_with("cal.csv:2:5: d_ref_mm is 90 mm"),
            "{e}"
        );
    }
}
