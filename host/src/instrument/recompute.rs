//! Old records evaluated with a new calibration (`jdbb recompute`): a `jdbb record` file
//! (`seq,t_us,enc1,enc2,d_mm`, any column order, extra columns kept) with `d_mm` recomputed from
//! `enc1` and `enc2` by the core model ([`jdbb_core::geometry::Model::distance_mm`]).
//!
//! Every other byte of the file is kept as it was: comment and blank lines, the header, the other
//! fields, the line endings. The new `d_mm` is written in full precision (the shortest decimal
//! that reads back as the same f64), so the file agrees with the model to the last bit. The
//! output is written by [`crate::fsio`] (a temporary file beside it, renamed when complete; an
//! existing output replaced only with `--force`); the input is never overwritten. Both files are streamed: a record of any length takes constant memory.
use std::io::{BufRead, BufReader, Write};
use std::path::Path;

use jdbb_core::calib::Calibration;
use jdbb_core::geometry::Model;

use crate::fsio::Staged;
use crate::table::Table;
use crate::{Error, Result};

/// Rewrite `record` to `out` with `d_mm` from `cal` (module docs). Returns the number of rows.
pub fn recompute(record: &Path, cal: &Calibration, out: &Path, force: bool) -> Result<usize> {
    crate::fsio::check_not_input(out, &[("the record", record)])?;
    let mut w = Staged::create(out, force)?;
    let rows = write_recomputed(record, cal, out, &mut w)?;
    w.commit()?;
    Ok(rows)
}

fn write_recomputed(record: &Path, cal: &Calibration, out: &Path, w: &mut Staged) -> Result<usize> {
    let mut table = Table::open(record)?;
    let cols = table.require(&["enc1", "enc2", "d_mm"])?;
    let d_index = cols[2].index;
    let input_err = |source| Error::InputFile {
        path: record.to_path_buf(),
        source,
    };
    let mut raw = BufReader::with_capacity(
        1 << 16,
        crate::fsio::open_input(record, crate::fsio::Limit::Stream)?,
    );
    let out_err = |source| Error::File {
        action: "cannot write",
        path: out.to_path_buf(),
        source,
    };
    let model = Model::new(cal);
    let mut line = Vec::with_capacity(256);
    let mut raw_no = 0usize;
    let mut rows = 0usize;
    let mut next_raw = |line: &mut Vec<u8>, raw_no: &mut usize| -> Result<bool> {
        line.clear();
        let n = raw.read_until(b'\n', line).map_err(input_err)?;
        *raw_no += 1;
        Ok(n > 0)
    };
    while let Some(row) = table.next_row()? {
        let e1 = row.integer(&cols[0])?;
        let e2 = row.integer(&cols[1])?;
        row.text(&cols[2])?;
        let d = model.distance_mm(e1, e2);
        if !d.is_finite() {
            return Err(row.error(
                &cols[0],
                "the instrument model gives no distance at these counts (a frame beyond ±86°); is this record from this instrument?",
            ));
        }
        // Copy every line before this row (header, comments, blank lines) as it is.
        while raw_no + 1 < row.line() {
            if !next_raw(&mut line, &mut raw_no)? {
                break;
            }
            w.write_all(&line).map_err(out_err)?;
        }
        if !next_raw(&mut line, &mut raw_no)? {
            return Err(Error::input(
                record,
                row.line(),
                0,
                "the file changed while it was read",
            ));
        }
        w.write_all(&replace_field(&line, d_index, &format!("{d}")))
            .map_err(out_err)?;
        rows += 1;
    }
    loop {
        if !next_raw(&mut line, &mut raw_no)? {
            break;
        }
        w.write_all(&line).map_err(out_err)?;
    }
    Ok(rows)
}

/// `line` with the trimmed text of comma-separated field `index` replaced by `value`; spaces
/// around the field and the line ending are kept.
fn replace_field(line: &[u8], index: usize, value: &str) -> Vec<u8> {
    let mut start = 0;
    for _ in 0..index {
        start += line[start..]
            .iter()
            .position(|&b| b == b',')
            .map_or(line.len() - start, |p| p + 1);
    }
    let rest = &line[start..];
    let end = start
        + rest
            .iter()
            .position(|&b| b == b',' || b == b'\r' || b == b'\n')
            .unwrap_or(rest.len());
    let field = &line[start..end];
    let lead = field
        .iter()
        .take_while(|b| **b == b' ' || **b == b'\t')
        .count();
    let trail = field
        .iter()
        .rev()
        .take_while(|b| **b == b' ' || **b == b'\t')
        .count();
    let trail = trail.min(field.len() - lead);
    let mut out = Vec::with_capacity(line.len() + 16);
    out.extend_from_slice(&line[..start + lead]);
    out.extend_from_slice(value.as_bytes());
    out.extend_from_slice(&line[end - trail..]);
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use jdbb_core::geometry::distance_mm;

    #[test]
    fn only_d_mm_changes() {
        let dir = tempfile::tempdir().unwrap();
        let rec = dir.path().join("rec.csv");
        let text = "# recorded by jdbb\r\nseq,t_us,enc1,enc2,d_mm,note\r\n0,0,1000,-2000, 99.9999990 ,a\r\n\r\n1,1000,-300000,250000,99.1234567,b\r\n# end\n";
        std::fs::write(&rec, text).unwrap();
        let mut cal = Calibration::DEFAULT;
        cal.l1_mm += 0.01;
        cal.enc2.zero_offset_rad = 1e-4;
        let out = dir.path().join("out.csv");
        assert_eq!(recompute(&rec, &cal, &out, false).unwrap(), 2);
        let got = std::fs::read_to_string(&out).unwrap();
        let d0 = distance_mm(&cal, 1000, -2000);
        let d1 = distance_mm(&cal, -300000, 250000);
        assert_eq!(
            got,
            format!("# recorded by jdbb\r\nseq,t_us,enc1,enc2,d_mm,note\r\n0,0,1000,-2000, {d0} ,a\r\n\r\n1,1000,-300000,250000,{d1},b\r\n# end\n")
        );
        assert_eq!(
            got.lines()
                .nth(2)
                .unwrap()
                .split(',')
                .nth(4)
                .unwrap()
                .trim()
                .parse::<f64>()
                .unwrap(),
            d0
        );
        // Only the output is left beside the record.
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 2);
    }

    #[test]
    fn refuses_to_overwrite_the_record_and_reports_bad_rows() {
        let dir = tempfile::tempdir().unwrap();
        let rec = dir.path().join("rec.csv");
        let text = "seq,t_us,enc1,enc2,d_mm\n0,0,1,2,100\n";
        std::fs::write(&rec, text).unwrap();
        let cal = Calibration::DEFAULT;
        let e = recompute(&rec, &cal, &rec, false).unwrap_err();
        assert_eq!(e.exit_code(), 2);
        let alias = dir.path().join(".").join("rec.csv");
        assert!(recompute(&rec, &cal, &alias, false).is_err());
        assert_eq!(std::fs::read_to_string(&rec).unwrap(), text);
        std::fs::write(&rec, "seq,t_us,enc1,enc2,d_mm\n0,0,1,2,100\n1,10,x,2,100\n").unwrap();
        let out = dir.path().join("out.csv");
        let e = recompute(&rec, &cal, &out, false).unwrap_err();
        assert!(
            e.to_string()
                .ends_with("rec.csv:3:6: enc1: `x` is not an integer"),
            "{e}"
        );
        assert!(!out.exists());
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
        let e = recompute(&dir.path().join("none.csv"), &cal, &out, false).unwrap_err();
        assert_eq!(e.exit_code(), 2);
    }

    #[test]
    fn fields_are_replaced_in_place() {
        assert_eq!(replace_field(b"a,b,c\n", 1, "X"), b"a,X,c\n");
        assert_eq!(replace_field(b"a,b,c", 2, "X"), b"a,b,X");
        assert_eq!(replace_field(b"a, b ,c\r\n", 1, "X"), b"a, X ,c\r\n");
        assert_eq!(replace_field(b"a,b,c\r\n", 2, "X"), b"a,b,X\r\n");
    }
}
