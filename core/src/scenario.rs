//! QEMU scenario files: what the simulated encoders of the `qemu` firmware build read, sample by
//! sample, instead of the built-in circle of [`crate::sim`].
//!
//! A scenario is a machine run already turned into encoder counts by a simulator on the host (the
//! tests' G-code machine runs a `jdbb plan` program with hidden errors, feed override, start delay,
//! noise and a wandering lean): the firmware streams it as the real board streams its encoders,
//! so the production protocol carries no simulation-only message. `scripts/qemu-run.sh
//! --scenario FILE` passes the file's path to QEMU as the semihosting command line; the firmware
//! opens it at boot and reads it as it samples.
//!
//! # Format (version 1, all integers little-endian)
//!
//! | bytes  | field        | meaning |
//! |--------|--------------|---------|
//! | 0..8   | magic        | `JDBBSCEN` |
//! | 8..10  | version      | `u16`, [`VERSION`] |
//! | 10..12 | reserved     | zero |
//! | 12..16 | `period_us`  | `u32`: time between two records on the device's clock (µs), ≥ 1 |
//! | 16..20 | `n_samples`  | `u32`: records that follow, ≥ 1 |
//! | 20..32 | reserved     | zero |
//! | 32..   | records      | `n_samples` × 8 bytes: encoder 1's then encoder 2's raw 32-bit counter value (`u32`) |
//!
//! Record k holds the counters at `t_us = k · period_us` after the run's start (the `Start` that
//! began the run, or boot): the sample taken at `t_us` reads record `⌊t_us / period_us⌋`; after the
//! last record the counters hold its values. A raw value is the extended count truncated to 32
//! bits, as TIM2/TIM5 hold it on the board; the firmware extends it as it extends theirs.

/// The first 8 bytes of every scenario file.
pub const MAGIC: [u8; 8] = *b"JDBBSCEN";
/// Version of the format described in the module docs.
pub const VERSION: u16 = 1;
/// Bytes before the first record.
pub const HEADER_LEN: usize = 32;
/// Bytes per record.
pub const RECORD_LEN: usize = 8;

/// The header of a scenario file.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Header {
    /// Time between records on the device's clock (µs).
    pub period_us: u32,
    /// Number of records.
    pub n_samples: u32,
}

/// Why bytes are not a usable scenario.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ScenarioError {
    /// Fewer than [`HEADER_LEN`] bytes.
    Truncated,
    /// The first 8 bytes are not [`MAGIC`]: not a scenario file.
    BadMagic,
    /// Written for another version of the format (the version found).
    UnsupportedVersion(u16),
    /// A reserved byte is not zero.
    Reserved,
    /// `period_us` is 0.
    ZeroPeriod,
    /// `n_samples` is 0.
    Empty,
}

impl Header {
    /// The header's bytes.
    pub fn encode(&self) -> [u8; HEADER_LEN] {
        let mut b = [0u8; HEADER_LEN];
        b[..8].copy_from_slice(&MAGIC);
        b[8..10].copy_from_slice(&VERSION.to_le_bytes());
        b[12..16].copy_from_slice(&self.period_us.to_le_bytes());
        b[16..20].copy_from_slice(&self.n_samples.to_le_bytes());
        b
    }

    /// Read and check a header from the first bytes of a file.
    pub fn decode(bytes: &[u8]) -> Result<Header, ScenarioError> {
        let b = bytes.get(..HEADER_LEN).ok_or(ScenarioError::Truncated)?;
        if b[..8] != MAGIC {
            return Err(ScenarioError::BadMagic);
        }
        let version = u16::from_le_bytes([b[8], b[9]]);
        if version != VERSION {
            return Err(ScenarioError::UnsupportedVersion(version));
        }
        if b[10..12].iter().chain(&b[20..32]).any(|&x| x != 0) {
            return Err(ScenarioError::Reserved);
        }
        let word = |i: usize| u32::from_le_bytes([b[i], b[i + 1], b[i + 2], b[i + 3]]);
        let h = Header {
            period_us: word(12),
            n_samples: word(16),
        };
        if h.period_us == 0 {
            return Err(ScenarioError::ZeroPeriod);
        }
        if h.n_samples == 0 {
            return Err(ScenarioError::Empty);
        }
        Ok(h)
    }

    /// Length of the whole file (bytes).
    pub fn file_len(&self) -> u64 {
        HEADER_LEN as u64 + RECORD_LEN as u64 * u64::from(self.n_samples)
    }

    /// The record the sample taken at `t_us` (after the run's start) reads: `⌊t_us / period_us⌋`,
    /// held at the last one.
    pub fn record_at(&self, t_us: u64) -> u32 {
        let k = t_us / u64::from(self.period_us);
        k.min(u64::from(self.n_samples - 1)) as u32
    }
}

/// The bytes of one record: the two counters' raw values.
pub fn encode_record(raw: [u32; 2]) -> [u8; RECORD_LEN] {
    let mut b = [0u8; RECORD_LEN];
    b[..4].copy_from_slice(&raw[0].to_le_bytes());
    b[4..].copy_from_slice(&raw[1].to_le_bytes());
    b
}

/// The two counters' raw values in a record.
pub fn decode_record(b: &[u8; RECORD_LEN]) -> [u32; 2] {
    [
        u32::from_le_bytes([b[0], b[1], b[2], b[3]]),
        u32::from_le_bytes([b[4], b[5], b[6], b[7]]),
    ]
}

/// The raw 32-bit counter value that holds extended count `count` (its low 32 bits).
pub fn raw_of(count: i64) -> u32 {
    count as u32
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::quadrature::CountExtender;

    /// The format is a contract between the host's scenario writers and the firmware.
    #[test]
    fn golden_header_and_record_bytes() {
        let h = Header {
            period_us: 200,
            n_samples: 100_000,
        };
        let b = h.encode();
        assert_eq!(
            b,
            [
                b'J', b'D', b'B', b'B', b'S', b'C', b'E', b'N', 1, 0, 0, 0, 0xc8, 0, 0, 0, 0xa0,
                0x86, 0x01, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0
            ]
        );
        assert_eq!(Header::decode(&b), Ok(h));
        assert_eq!(h.file_len(), 32 + 800_000);
        let r = encode_record([raw_of(1_747_626), raw_of(-3)]);
        assert_eq!(r, [0xaa, 0xaa, 0x1a, 0x00, 0xfd, 0xff, 0xff, 0xff]);
        assert_eq!(decode_record(&r), [1_747_626, 0xffff_fffd]);
    }

    #[test]
    fn bad_headers_are_refused_with_their_reason() {
        let good = Header {
            period_us: 1000,
            n_samples: 5,
        }
        .encode();
        assert_eq!(Header::decode(&good[..31]), Err(ScenarioError::Truncated));
        let mut b = good;
        b[0] = b'X';
        assert_eq!(Header::decode(&b), Err(ScenarioError::BadMagic));
        let mut b = good;
        b[8] = 2;
        assert_eq!(
            Header::decode(&b),
            Err(ScenarioError::UnsupportedVersion(2))
        );
        let mut b = good;
        b[31] = 1;
        assert_eq!(Header::decode(&b), Err(ScenarioError::Reserved));
        let mut b = good;
        b[12..16].fill(0);
        assert_eq!(Header::decode(&b), Err(ScenarioError::ZeroPeriod));
        let mut b = good;
        b[16..20].fill(0);
        assert_eq!(Header::decode(&b), Err(ScenarioError::Empty));
    }

    #[test]
    fn records_are_picked_by_time_and_held_at_the_end() {
        let h = Header {
            period_us: 200,
            n_samples: 10,
        };
        assert_eq!(h.record_at(0), 0);
        assert_eq!(h.record_at(199), 0);
        assert_eq!(h.record_at(200), 1);
        // A 1 kHz run reads every fifth record of a 5 kHz scenario.
        assert_eq!(h.record_at(1000), 5);
        assert_eq!(h.record_at(1_000_000), 9);
    }

    /// Raw values are the counters' low 32 bits: the firmware's extension gives back the counts,
    /// across the 32-bit wrap and for negative counts.
    #[test]
    fn raw_values_extend_back_to_the_counts() {
        let counts = [-5i64, 3, 1 << 31, (1 << 32) + 7, -(1 << 31) - 9];
        let mut ext = CountExtender::<32>::new(raw_of(counts[0]), counts[0]);
        for w in counts.windows(2) {
            // Steps of up to 2³¹ − 1 counts between samples extend unambiguously.
            let mut c = w[0];
            let step = (w[1] - w[0]).signum() * ((1i64 << 30) - 1);
            while (w[1] - c).abs() > step.abs() {
                c += step;
                assert_eq!(ext.update(raw_of(c)), c);
            }
            assert_eq!(ext.update(raw_of(w[1])), w[1]);
        }
    }
}
