//! The device's sample path, free of hardware: two raw counter readings in, a [`SampleBatch`] out
//! every [`BATCH_LEN`](crate::protocol::BATCH_LEN) samples. The firmware's sample-clock task calls [`Sampler::sample`] and
//! nothing else, on the real board and in QEMU alike; the cycle-count program times exactly this
//! plus the frame encoding.
//!
//! No allocation, no panic path: every operation is total (wrapping sequence numbers, saturating
//! drop counter, a batch that is sealed the moment it is full).

use crate::calib::Calibration;
use crate::geometry::{Kernel, FRAME_RANGE_RAD};
use crate::protocol::{Sample, SampleBatch, Status};
use crate::quadrature::Encoder;

/// Time of the sample clock in whole µs, advanced by one period per tick without drift: the period
/// of `ticks` timer-clock cycles at `clock_hz` is rarely a whole number of µs, so the remainder is
/// carried exactly (integer arithmetic only, no division per tick).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SampleClock {
    t_us: u64,
    frac: u32,
    step_us: u32,
    step_frac: u32,
    clock_hz: u32,
}

impl SampleClock {
    /// A clock at t = 0 whose period is `period_ticks` cycles of a `clock_hz` timer clock.
    pub fn new(clock_hz: u32, period_ticks: u32) -> Self {
        let mut c = SampleClock {
            t_us: 0,
            frac: 0,
            step_us: 0,
            step_frac: 0,
            clock_hz: clock_hz.max(1),
        };
        c.set_period(clock_hz, period_ticks);
        c
    }

    /// Change the period from the next tick on; the time reached so far is kept.
    pub fn set_period(&mut self, clock_hz: u32, period_ticks: u32) {
        let clock_hz = clock_hz.max(1);
        let num = period_ticks as u64 * 1_000_000;
        self.step_us = (num / clock_hz as u64) as u32;
        self.step_frac = (num % clock_hz as u64) as u32;
        // Rescale the carried fraction to the new clock (exact when the clock is unchanged).
        self.frac = (self.frac as u64 * clock_hz as u64 / self.clock_hz as u64) as u32;
        self.clock_hz = clock_hz;
    }

    /// Time of the current tick (µs).
    #[inline]
    pub fn now_us(&self) -> u64 {
        self.t_us
    }

    /// Advance by one period.
    #[inline]
    pub fn tick(&mut self) {
        self.t_us += self.step_us as u64;
        self.frac += self.step_frac;
        if self.frac >= self.clock_hz {
            self.frac -= self.clock_hz;
            self.t_us += 1;
        }
    }

    /// Back to t = 0.
    pub fn reset(&mut self) {
        self.t_us = 0;
        self.frac = 0;
    }
}

/// Counts → D → [`Sample`] → [`SampleBatch`], with sequence numbers and counted drops.
#[derive(Debug, Clone)]
pub struct Sampler {
    enc: [Encoder<32>; 2],
    kernel: Kernel,
    range_rad: f32,
    clock: SampleClock,
    next_seq: u32,
    dropped: u32,
    base_status: u8,
    batch: SampleBatch,
}

impl Sampler {
    /// A sampler whose counters currently read `raw`, computing D with `cal`, timed by `clock`.
    /// `simulated` sets [`Status::SIMULATED`] in every sample.
    pub fn new(raw: [u32; 2], cal: &Calibration, clock: SampleClock, simulated: bool) -> Self {
        Sampler {
            enc: [Encoder::new(raw[0]), Encoder::new(raw[1])],
            kernel: Kernel::new(cal),
            range_rad: FRAME_RANGE_RAD as f32,
            clock,
            next_seq: 0,
            dropped: 0,
            base_status: if simulated { Status::SIMULATED } else { 0 },
            batch: SampleBatch {
                seq: 0,
                dropped: 0,
                samples: heapless::Vec::new(),
            },
        }
    }

    /// Take one sample from the two counters' raw values; returns the batch when it is full.
    /// Sample times come from the sample clock, which advances by one period per call.
    #[inline]
    pub fn sample(&mut self, raw: [u32; 2]) -> Option<SampleBatch> {
        let enc1 = self.enc[0].update(raw[0]);
        let enc2 = self.enc[1].update(raw[1]);
        let d_mm = self.kernel.distance_mm(enc1, enc2);
        let (alpha, beta) = self.kernel.frame_angles_rad(enc1, enc2);
        let mut status = self.base_status;
        if self.enc[0].is_referenced() {
            status |= Status::ENC1_REFERENCED;
        }
        if self.enc[1].is_referenced() {
            status |= Status::ENC2_REFERENCED;
        }
        // `!(x <= r)` also flags NaN.
        if !(alpha.abs() <= self.range_rad && beta.abs() <= self.range_rad) {
            status |= Status::OUT_OF_RANGE;
        }
        let sample = Sample {
            t_us: self.clock.now_us(),
            enc1,
            enc2,
            d_mm,
            status: Status(status),
        };
        self.clock.tick();
        if self.batch.samples.is_empty() {
            self.batch.seq = self.next_seq;
        }
        self.next_seq = self.next_seq.wrapping_add(1);
        // Cannot fail: a full batch is sealed below before the next push.
        let _ = self.batch.samples.push(sample);
        if self.batch.samples.is_full() {
            self.take_batch()
        } else {
            None
        }
    }

    /// Seal and return the samples collected so far (e.g. when sampling stops), if any.
    pub fn take_batch(&mut self) -> Option<SampleBatch> {
        if self.batch.samples.is_empty() {
            return None;
        }
        let mut out = SampleBatch {
            seq: self.next_seq,
            dropped: self.dropped,
            samples: heapless::Vec::new(),
        };
        core::mem::swap(&mut out, &mut self.batch);
        out.dropped = self.dropped;
        Some(out)
    }

    /// The caller could not deliver `n` samples (queue or link full): count them. Sequence numbers
    /// are not reused, so the host sees the gap and the total in the next batch's `dropped`.
    #[inline]
    pub fn count_dropped(&mut self, n: u32) {
        self.dropped = self.dropped.saturating_add(n);
    }

    /// Restart sequence numbers, time and the drop counter (the host's `Start`); any unfinished
    /// batch is discarded.
    pub fn restart(&mut self) {
        self.next_seq = 0;
        self.dropped = 0;
        self.clock.reset();
        self.batch.samples.clear();
    }

    /// Time the next sample will carry (µs since sampling started).
    pub fn next_t_us(&self) -> u64 {
        self.clock.now_us()
    }

    /// Total samples dropped since sampling started.
    pub fn dropped(&self) -> u32 {
        self.dropped
    }

    /// Change the sample period (see [`SampleClock::set_period`]).
    pub fn set_period(&mut self, clock_hz: u32, period_ticks: u32) {
        self.clock.set_period(clock_hz, period_ticks);
    }

    /// Compute D with a new calibration from the next sample on.
    pub fn set_calibration(&mut self, cal: &Calibration) {
        self.kernel = Kernel::new(cal);
    }

    /// Encoder `ch` (0 or 1; others ignored) passed its index while its counter read `raw`.
    pub fn on_index(&mut self, ch: usize, raw: u32) {
        if let Some(e) = self.enc.get_mut(ch) {
            e.on_index(raw);
        }
    }

    /// Whether encoder `ch` is referenced.
    pub fn is_referenced(&self, ch: usize) -> bool {
        self.enc.get(ch).is_some_and(|e| e.is_referenced())
    }

    /// Make the current position of both encoders count zero (the host's `Zero`).
    pub fn zero_here(&mut self) {
        for e in &mut self.enc {
            e.zero_here();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry;
    use crate::protocol::BATCH_LEN;

    fn sampler() -> Sampler {
        // 96 MHz timer clock, 1 kHz.
        Sampler::new(
            [0, 0],
            &Calibration::DEFAULT,
            SampleClock::new(96_000_000, 96_000),
            false,
        )
    }

    #[test]
    fn clock_carries_fraction_exactly() {
        // 3 kHz from 1 GHz: 333 333 ticks = 333.333 µs. After 3000 ticks exactly 1 s.
        let mut c = SampleClock::new(1_000_000_000, 333_333);
        for _ in 0..3000 {
            c.tick();
        }
        assert_eq!(c.now_us(), 999_999); // 3000 × 333.333 µs = 999 999 µs
        let mut c = SampleClock::new(96_000_000, 32_000); // exactly 3 kHz
        for _ in 0..3000 {
            c.tick();
        }
        assert_eq!(c.now_us(), 1_000_000);
    }

    #[test]
    fn batches_carry_seq_time_and_d() {
        let mut s = sampler();
        let mut batches = std::vec::Vec::new();
        for i in 0..(3 * BATCH_LEN as u32 + 5) {
            if let Some(b) = s.sample([i, (i as i32 * -3) as u32]) {
                batches.push(b);
            }
        }
        assert_eq!(batches.len(), 3);
        for (k, b) in batches.iter().enumerate() {
            assert_eq!(b.seq as usize, k * BATCH_LEN);
            assert_eq!(b.samples.len(), BATCH_LEN);
            for (j, smp) in b.samples.iter().enumerate() {
                let i = (k * BATCH_LEN + j) as i64;
                assert_eq!(smp.t_us, 1000 * i as u64);
                assert_eq!((smp.enc1, smp.enc2), (i, -3 * i));
                let d = geometry::distance_mm(&Calibration::DEFAULT, i, -3 * i);
                assert!((smp.d_mm - d).abs() < 1e-5);
                assert_eq!(smp.status, Status(0));
            }
        }
        // The 5 left over come out on demand, then nothing.
        let rest = s.take_batch().unwrap();
        assert_eq!((rest.seq, rest.samples.len()), (48, 5));
        assert!(s.take_batch().is_none());
    }

    #[test]
    fn drops_are_counted_and_seq_shows_the_gap() {
        let mut s = sampler();
        let mut delivered = std::vec::Vec::new();
        for i in 0..(4 * BATCH_LEN as u32) {
            if let Some(b) = s.sample([i, i]) {
                if b.seq == BATCH_LEN as u32 {
                    // Queue full: the second batch is lost.
                    s.count_dropped(b.samples.len() as u32);
                } else {
                    delivered.push(b);
                }
            }
        }
        let seqs: std::vec::Vec<u32> = delivered.iter().map(|b| b.seq).collect();
        assert_eq!(seqs, [0, 32, 48]);
        let drops: std::vec::Vec<u32> = delivered.iter().map(|b| b.dropped).collect();
        assert_eq!(drops, [0, 16, 16]);
        s.restart();
        let b = (0..BATCH_LEN as u32)
            .find_map(|i| s.sample([i, i]))
            .unwrap();
        assert_eq!((b.seq, b.dropped, b.samples[0].t_us), (0, 0, 0));
    }

    #[test]
    fn status_flags_reference_and_range() {
        let mut s = Sampler::new(
            [0, 0],
            &Calibration::DEFAULT,
            SampleClock::new(1_000_000, 1000),
            true,
        );
        let last = |b: Option<SampleBatch>, s: &mut Sampler| {
            b.or_else(|| s.take_batch()).unwrap().samples[0].status
        };
        // 75° at 20 000 counts/rev is 4166.7 counts: 4166 inside, 4167 outside.
        let st = last(s.sample([4166, (-4166i32) as u32]), &mut s);
        assert_eq!(st, Status(Status::SIMULATED));
        let st = last(s.sample([4167, 0]), &mut s);
        assert!(st.has(Status::OUT_OF_RANGE | Status::SIMULATED));
        s.on_index(0, 100); // encoder 1's index at raw 100
        let b = s.sample([100, 0]).or_else(|| s.take_batch()).unwrap();
        assert_eq!(b.samples[0].enc1, 0);
        assert_eq!(
            b.samples[0].status,
            Status(Status::SIMULATED | Status::ENC1_REFERENCED)
        );
        s.zero_here();
        let b = s.sample([110, 0]).or_else(|| s.take_batch()).unwrap();
        assert_eq!((b.samples[0].enc1, b.samples[0].enc2), (10, 0));
        assert!(b.samples[0]
            .status
            .has(Status::ENC1_REFERENCED | Status::ENC2_REFERENCED));
    }
}
