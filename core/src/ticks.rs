//! The board's 32-bit count of sample-clock ticks, read from two 16-bit timers: TIM4 counts the
//! ticks (the low half) and TIM1 counts TIM4's overflows (the high half). TIM1 is clocked by
//! TIM4's update event through its slave controller, which resynchronises the trigger: it counts
//! the overflow a few timer clocks *after* TIM4 wrapped to 0. A read of high, low, high that
//! falls in that window sees the new low half (0) with the old high half twice, and a
//! "high unchanged" check alone returns a count 65 536 low (issue 32 §4).
//!
//! [`read_tick_count`] closes the window: the only ambiguous low half is 0 (ticks are at least a
//! sample period apart, thousands of CPU cycles, while the lag is a few), so on a 0 it waits out
//! the lag and reads the high half again. It is proved here against a model of the two timers
//! in which the high half lags by up to [`MAX_LAG_READS`] register reads, at every phase of a
//! wrap against the reads.

/// The longest lag of the high half behind the low half's wrap the settle wait must exceed, in
/// register reads (each at least one bus cycle): the model's bound. The board's settle wait is
/// 32 CPU cycles against a lag of 2–3 timer clocks (RM0383, external clock mode 1: the trigger
/// is resynchronised on the timer clock).
pub const MAX_LAG_READS: u32 = 8;

/// The 32-bit tick count from `read_lo` (the low 16 bits, counting every tick), `read_hi` (the
/// high 16 bits, counting the low half's overflows, possibly late) and `settle` (a wait longer
/// than that lateness and much shorter than a tick period). The result is the true count at some
/// instant during the call.
#[inline]
pub fn read_tick_count(
    mut read_lo: impl FnMut() -> u16,
    mut read_hi: impl FnMut() -> u16,
    mut settle: impl FnMut(),
) -> u32 {
    loop {
        let h1 = read_hi();
        let l = read_lo();
        let h2 = read_hi();
        if h1 != h2 {
            continue; // the high half counted meanwhile: read again (the lag is over now)
        }
        if l != 0 {
            // The low half did not just wrap, so the high half that matches it is h1: read
            // before and after it and unchanged (an overflow after `l` shows in neither read or
            // only in h2, which was equal).
            return (u32::from(h1) << 16) | u32::from(l);
        }
        // Low half 0: it may have wrapped a moment ago with the high half not counted yet.
        settle();
        let h3 = read_hi();
        if read_lo() == 0 {
            return u32::from(h3) << 16;
        }
        // A tick came during the wait (cannot with a settle shorter than a period): again.
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use core::cell::Cell;

    /// The two timers: ticks at `first + k·period` (model time, one unit per register read),
    /// starting from the count `start`; the high half sees an overflow `lag` units late.
    struct Model {
        start: u32,
        first: u64,
        period: u64,
        lag: u64,
        now: Cell<u64>,
    }

    impl Model {
        fn count_at(&self, t: u64) -> u32 {
            let ticks = if t < self.first {
                0
            } else {
                (t - self.first) / self.period + 1
            };
            self.start.wrapping_add(ticks as u32)
        }
        fn lo(&self) -> u16 {
            let t = self.now.get();
            self.now.set(t + 1);
            self.count_at(t) as u16
        }
        fn hi(&self) -> u16 {
            let t = self.now.get();
            self.now.set(t + 1);
            (self.count_at(t.saturating_sub(self.lag)) >> 16) as u16
        }
    }

    /// What the board did before issue 32: high, low, high, and the low half read again with
    /// the second high half when they differ.
    fn old_read(m: &Model) -> u32 {
        let h1 = m.hi();
        let l = m.lo();
        let h2 = m.hi();
        if h1 == h2 {
            (u32::from(h1) << 16) | u32::from(l)
        } else {
            (u32::from(h2) << 16) | u32::from(m.lo())
        }
    }

    #[test]
    fn the_count_is_exact_at_every_phase_of_a_wrap() {
        let settle = u64::from(MAX_LAG_READS) + 1;
        let mut old_wrong = 0;
        for lag in 0..=u64::from(MAX_LAG_READS) {
            for start in [0xffff_ffff_u32, 0x0000_ffff, 0x1234_ffff, 0x1234_fffe] {
                // Ticks 40 reads apart (the board: thousands of cycles), the wrap placed at
                // every read of the call.
                for first in 0..40 {
                    let m = Model {
                        start,
                        first,
                        period: 40,
                        lag,
                        now: Cell::new(10),
                    };
                    let t0 = m.now.get();
                    let got =
                        read_tick_count(|| m.lo(), || m.hi(), || m.now.set(m.now.get() + settle));
                    let t1 = m.now.get();
                    // Linearisable: the true count at some instant of the call.
                    assert!(
                        (t0..t1).any(|t| m.count_at(t) == got),
                        "lag {lag}, start {start:#x}, first {first}: got {got:#x}"
                    );
                    m.now.set(10);
                    let old = old_read(&m);
                    if !(10..m.now.get()).any(|t| m.count_at(t) == old) {
                        old_wrong += 1;
                        assert_eq!(
                            old.wrapping_add(0x1_0000) >> 16,
                            m.count_at(m.now.get()) >> 16
                        );
                    }
                }
            }
        }
        // The old read was wrong (65 536 low) whenever the wrap fell in the lag window.
        assert!(old_wrong > 0);
    }
}
