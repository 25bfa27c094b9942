//! Raw records kept with their runs (`jdbb history add --keep-record REC.csv [--plan PLAN.json]`),
//! so that a diagnosis can be re-run later with a newer jdbb and compared (`jdbb history rerun`).
//!
//! - Each kept file (the record; the plan it was run with, if any) is one row of the table
//!   `kept_files` (migration 5 of [`super::schema`]; on a server, [`super::pg`]'s migration 5):
//!   its role, its file name as given, its size, its SHA-256 and its bytes gzip-compressed.
//! - Compressed with `flate2` (gzip: a kept blob written out is read by `zcat`); the README's
//!   record (6.25 MB of CSV) shrinks sixfold, to 1.05 MB.
//! - Checksummed with SHA-256 (`sha2`, already built for the PostgreSQL client's password
//!   exchange) of the file as it was read: a flipped byte anywhere (in the blob, or decompressing
//!   to something else) is caught before the record is used. A CRC-32 would catch a random
//!   flip too, but the kept record is the evidence behind a run's results, and SHA-256 also
//!   shows that nobody changed it on purpose.
//! - A kept file goes in the same transaction as its run; it leaves with the run
//!   (`history remove`) and moves with it (`history migrate`, its SHA-256 part of the run's
//!   checksum there).
//!
//! May use: flate2, sha2.
use std::io::{Read, Write};
use std::path::Path;

use sha2::{Digest, Sha256};

use crate::{Error, Result};

/// What a kept file is to its run.
pub const RECORD: &str = "record";
/// The plan the record was run with (`diagnose --record --plan`).
pub const PLAN: &str = "plan";

/// One file kept with a run.
#[derive(Clone, PartialEq)]
pub struct KeptFile {
    /// [`RECORD`] or [`PLAN`].
    pub role: String,
    /// The file's name as it was given (for messages; a re-run restores it under its base name).
    pub name: String,
    /// The file's size, bytes (uncompressed).
    pub size_bytes: i64,
    /// SHA-256 of the file's bytes, 64 hex digits.
    pub sha256: String,
    /// The file's bytes, gzip-compressed.
    pub gzip: Vec<u8>,
}

impl std::fmt::Debug for KeptFile {
    // The checksum stands for the bytes: a run's Debug text (its checksum in `history migrate`)
    // stays short.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("KeptFile")
            .field("role", &self.role)
            .field("name", &self.name)
            .field("size_bytes", &self.size_bytes)
            .field("sha256", &self.sha256)
            .finish_non_exhaustive()
    }
}

/// SHA-256 of `bytes` as 64 hex digits.
pub fn sha256_hex(bytes: &[u8]) -> String {
    Sha256::digest(bytes)
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect()
}

impl KeptFile {
    /// Read the file `path` (a record: up to the size of a table read whole; a plan: a
    /// document) and pack it to be kept as `role`.
    pub fn read(role: &str, path: &Path) -> Result<KeptFile> {
        let limit = if role == PLAN {
            crate::fsio::Limit::Document
        } else {
            crate::fsio::Limit::Table
        };
        let bytes = crate::fsio::read_input(path, limit)?;
        Ok(Self::pack(role, &path.display().to_string(), &bytes))
    }

    /// `bytes` (of the file `name`) packed to be kept as `role`.
    pub fn pack(role: &str, name: &str, bytes: &[u8]) -> KeptFile {
        let mut gz = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::default());
        gz.write_all(bytes)
            .and_then(|()| gz.finish())
            .map(|gzip| KeptFile {
                role: role.to_string(),
                name: name.to_string(),
                size_bytes: bytes.len() as i64,
                sha256: sha256_hex(bytes),
                gzip,
            })
            .expect("compressing into memory does not fail")
    }

    /// The file's bytes as they were read, checked against the size and SHA-256 filed with them;
    /// a damaged blob (run `run_id` of the history at `location`) is refused, saying so.
    pub fn unpack(&self, run_id: i64, location: &str) -> Result<Vec<u8>> {
        let damaged = |why: String| {
            Error::Input {
            location: format!("{location}, run {run_id}, kept {}", self.role),
            message: format!(
                "the kept {} ({}) is damaged: {why}; it is not used. The run's stored results stand; keep the record again with `jdbb history remove` and `jdbb history add --keep-record` from the original file",
                self.role,
                super::printable(&self.name)
            ),
        }
        };
        let mut bytes = Vec::with_capacity(usize::try_from(self.size_bytes).unwrap_or(0));
        let limit = u64::try_from(self.size_bytes).unwrap_or(0) + 1;
        flate2::read::GzDecoder::new(self.gzip.as_slice())
            .take(limit)
            .read_to_end(&mut bytes)
            .map_err(|e| damaged(format!("it does not decompress ({e})")))?;
        if bytes.len() as i64 != self.size_bytes {
            return Err(damaged(format!(
                "it decompresses to {} bytes, not the {} filed",
                bytes.len(),
                self.size_bytes
            )));
        }
        let sum = sha256_hex(&bytes);
        if sum != self.sha256 {
            return Err(damaged(format!(
                "its SHA-256 is {sum}, not the {} filed",
                self.sha256
            )));
        }
        Ok(bytes)
    }

    /// The base name to restore the file under (the role's if the name has none).
    pub fn base_name(&self) -> String {
        Path::new(&self.name)
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .filter(|n| !n.is_empty() && !n.starts_with('.'))
            .unwrap_or_else(|| format!("{}.kept", self.role))
    }
}

/// What a run keeps for a re-run: its diagnosis file as filed, its effects, and its kept files.
#[derive(Debug, Clone)]
pub struct Kept {
    pub run: super::Run,
    /// The diagnosis file's text as filed.
    pub diagnosis: String,
    /// The kept files, the record first.
    pub files: Vec<KeptFile>,
}

/// The stored effects of a run beside those of its re-run, one row per effect (in the stored
/// order, then the new ones): value ± σ each, in the digits its σ supports, and the difference
/// in the stored σ (`+0.00 σ`: the same result). An effect one side lacks says so.
pub fn compare(stored: &[super::EffectRow], now: &[super::EffectRow]) -> String {
    use crate::units::{format_to, human};
    use std::fmt::Write;
    let cell = |e: Option<&super::EffectRow>| match e {
        Some(e) => match (e.value, e.sigma) {
            (Some(v), Some(s)) => format!("{} ± {}", format_to(v, s), format_to(s, s)),
            (Some(v), None) => format!("{v:.3}"),
            (None, _) => "-".into(),
        },
        None => "(not named)".into(),
    };
    let mut names: Vec<(&str, &str)> = stored
        .iter()
        .map(|e| (e.name.as_str(), e.unit.as_str()))
        .collect();
    for e in now {
        if !names.iter().any(|(n, _)| *n == e.name) {
            names.push((&e.name, &e.unit));
        }
    }
    let mut out = format!(
        "{:<22} {:<8} {:<20} {:<20} {}\n",
        "effect", "unit", "stored ± σ", "now ± σ", "difference"
    );
    for (name, unit) in names {
        let a = stored.iter().find(|e| e.name == name);
        let b = now.iter().find(|e| e.name == name);
        let diff = match (a, b) {
            (Some(a), Some(b)) => match (a.value, a.sigma, b.value) {
                (Some(va), Some(sa), Some(vb)) if sa > 0.0 => format!("{:+.2} σ", (vb - va) / sa),
                (Some(va), _, Some(vb)) if va == vb => "same".into(),
                _ => "-".into(),
            },
            (Some(_), None) => "no longer named".into(),
            _ => "newly named".into(),
        };
        let _ = writeln!(
            out,
            "{:<22} {:<8} {:<20} {:<20} {diff}",
            super::printable(name),
            human(unit),
            cell(a),
            cell(b)
        );
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_kept_file_unpacks_to_its_bytes_and_a_flipped_byte_is_refused() {
        let text = "seq,t_us,enc1,enc2,d_mm\n".repeat(200);
        let k = KeptFile::pack(RECORD, "rec.csv", text.as_bytes());
        assert!(k.gzip.len() * 4 < text.len(), "{} bytes", k.gzip.len());
        assert_eq!(k.unpack(1, "h.sqlite").unwrap(), text.as_bytes());
        for at in [12, k.gzip.len() / 2, k.gzip.len() - 6] {
            let mut bad = k.clone();
            bad.gzip[at] ^= 0x10;
            let e = bad.unpack(1, "h.sqlite").unwrap_err().to_string();
            assert!(e.contains("is damaged"), "byte {at}: {e}");
        }
    }

    #[test]
    fn the_difference_is_in_the_stored_sigma() {
        let row = |v: f64, s: f64| super::super::EffectRow {
            name: "backlash_x".into(),
            value: Some(v),
            sigma: Some(s),
            unit: "um".into(),
        };
        let t = compare(&[row(8.0, 0.5)], &[row(9.0, 0.25)]);
        assert!(t.contains("+2.00 σ"), "{t}");
        let t = compare(&[row(8.0, 0.5)], &[]);
        assert!(t.contains("no longer named"), "{t}");
    }
}
