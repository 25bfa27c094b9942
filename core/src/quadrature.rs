//! Quadrature counts: extend a wrapping 16- or 32-bit hardware counter to a continuous `i64`, and
//! reference it to the encoder's index pulse.
//!
//! The extension is correct as long as the counter moves by less than half its range between two
//! reads (32 767 counts for a 16-bit timer: at 20 000 counts/rev that is 1.6 rev per sample period).

/// Extends a wrapping hardware count of `BITS` bits (16 or 32) to a continuous `i64`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CountExtender<const BITS: u32> {
    last_raw: u32,
    count: i64,
}

impl<const BITS: u32> CountExtender<BITS> {
    const MASK: u32 = if BITS >= 32 {
        u32::MAX
    } else {
        (1u32 << BITS) - 1
    };

    /// Start from the counter's current raw value, which becomes extended count `initial`.
    pub const fn new(raw: u32, initial: i64) -> Self {
        CountExtender {
            last_raw: raw & Self::MASK,
            count: initial,
        }
    }

    /// Feed the counter's current raw value; returns the extended count. The step since the last
    /// read is taken as the shortest way round the counter's range.
    #[inline]
    pub fn update(&mut self, raw: u32) -> i64 {
        let raw = raw & Self::MASK;
        let diff = raw.wrapping_sub(self.last_raw) & Self::MASK;
        // Sign-extend the BITS-bit difference.
        let shift = 32 - BITS;
        let step = ((diff << shift) as i32 >> shift) as i64;
        self.last_raw = raw;
        self.count += step;
        self.count
    }

    /// The extended count at the last update.
    pub fn count(&self) -> i64 {
        self.count
    }
}

/// One encoder channel: count extension plus index referencing. Until the index pulse is seen,
/// counts are relative to power-up; from then on, the count latched at the index is zero.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Encoder<const BITS: u32> {
    ext: CountExtender<BITS>,
    index_offset: Option<i64>,
}

impl<const BITS: u32> Encoder<BITS> {
    /// A channel whose counter currently reads `raw` (extended count 0, unreferenced).
    pub const fn new(raw: u32) -> Self {
        Encoder {
            ext: CountExtender::new(raw, 0),
            index_offset: None,
        }
    }

    /// Feed the counter's current raw value; returns the referenced count (relative to the index
    /// once seen, to power-up before).
    #[inline]
    pub fn update(&mut self, raw: u32) -> i64 {
        let c = self.ext.update(raw);
        c - self.index_offset.unwrap_or(0)
    }

    /// The index pulse fired while the hardware counter read `raw_at_index` (latched by a capture
    /// channel): from now on that position is count zero. Must be called before the counter has
    /// moved half its range past the latch.
    pub fn on_index(&mut self, raw_at_index: u32) {
        let mut probe = self.ext;
        let at_index = probe.update(raw_at_index);
        self.index_offset = Some(at_index);
    }

    /// Make the current position count zero (the host's `Zero` command).
    pub fn zero_here(&mut self) {
        self.index_offset = Some(self.ext.count());
    }

    /// Whether counts are referenced (to the index pulse or an explicit zero).
    pub fn is_referenced(&self) -> bool {
        self.index_offset.is_some()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn wraps_forward_and_back_16_bit() {
        let mut e = CountExtender::<16>::new(65_530, 0);
        assert_eq!(e.update(65_535), 5);
        assert_eq!(e.update(4), 10); // wrapped forward
        assert_eq!(e.update(65_530), 0); // wrapped back
        assert_eq!(e.update(65_000), -530);
    }

    #[test]
    fn wraps_32_bit() {
        let mut e = CountExtender::<32>::new(u32::MAX - 1, 100);
        assert_eq!(e.update(3), 105);
        assert_eq!(e.update(u32::MAX), 101);
    }

    #[test]
    fn index_references_to_latch() {
        let mut enc = Encoder::<16>::new(1000);
        assert_eq!(enc.update(1100), 100);
        assert!(!enc.is_referenced());
        enc.on_index(1050); // index passed at raw 1050
        assert!(enc.is_referenced());
        assert_eq!(enc.update(1100), 50);
        assert_eq!(enc.update(1000), -50);
        enc.zero_here();
        assert_eq!(enc.update(1010), 10);
    }

    fn check_walk<const B: u32>(start: u32, steps: &[i32]) -> Result<(), TestCaseError> {
        let mask: u64 = if B >= 32 {
            u32::MAX as u64
        } else {
            (1u64 << B) - 1
        };
        let mut e = CountExtender::<B>::new(start, 0);
        let mut truth: i64 = 0;
        for &s in steps {
            truth += s as i64;
            let raw = ((start as i64 + truth).rem_euclid(mask as i64 + 1)) as u32;
            prop_assert_eq!(e.update(raw), truth);
        }
        Ok(())
    }

    proptest! {
        #[test]
        fn extension_follows_any_walk_16(start in 0u32..65_536, steps in prop::collection::vec(-32_767i32..=32_767, 0..200)) {
            check_walk::<16>(start, &steps)?;
        }

        #[test]
        fn extension_follows_any_walk_32(start in any::<u32>(), steps in prop::collection::vec(-2_000_000_000i32..=2_000_000_000, 0..200)) {
            check_walk::<32>(start, &steps)?;
        }
    }
}
