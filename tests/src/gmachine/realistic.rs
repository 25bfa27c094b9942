//! A machine as a shop has one (issue 26): axes on real position loops and a trace with coloured
//! noise, drawn from a seed. What the tests of planned runs draw their machines' dynamics from,
//! so that a hidden effect is found on a machine that moves like a machine and not only on one
//! that follows its program exactly.
//!
//! The envelope (docs/mechanisms.md, "Machine dynamics"): position loops of Kv 30–60 s⁻¹ with a
//! 50–200 Hz velocity loop, either modern (velocity feed-forward 0.9–1.0, some acceleration
//! feed-forward) or without feed-forward; the axes alike (a difference is a servo mismatch, an
//! effect of its own) and held on 0.1, 0.5 or 1 µm counts; AR(1) noise of 0.05–0.3 µm with a
//! correlation of 0.3–0.8 between samples, a 1/f wander of up to 0.2 µm and a vibration of up to
//! 0.1 µm at 15–120 Hz, over white noise of 0.05–0.2 µm.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::dynamics::{ColouredNoise, ServoLoop};
use super::SimConfig;

/// Which position loops to draw.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Tuning {
    /// Velocity feed-forward 0.9–1.0 and acceleration feed-forward 0–1: a current control.
    Modern,
    /// No feed-forward: the axis follows its command 1/Kv late and a circle is drawn small.
    NoFeedForward,
    /// Modern three times in five, else without feed-forward.
    Either,
}

/// One machine's loops and its trace's noise.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Realistic {
    /// The same loop on every axis.
    pub servo: ServoLoop,
    /// The coloured part of the noise.
    pub noise: ColouredNoise,
    /// The white part (µm, standard deviation).
    pub white_um: f64,
}

impl Realistic {
    /// The draw of `seed` for a record sampled at `rate_hz` (the AR(1)'s correlation is per
    /// sample, so its time constant follows the rate).
    pub fn draw(seed: u64, rate_hz: f64, tuning: Tuning) -> Self {
        Self::draw_from(
            &mut ChaCha8Rng::seed_from_u64(0x7265_616c ^ seed),
            rate_hz,
            tuning,
        )
    }

    /// [`Self::draw`] from a stream a test already draws its case from.
    pub fn draw_from(r: &mut impl Rng, rate_hz: f64, tuning: Tuning) -> Self {
        let modern = match tuning {
            Tuning::Modern => true,
            Tuning::NoFeedForward => false,
            Tuning::Either => r.gen_bool(0.6),
        };
        let kv_per_s = r.gen_range(30.0..60.0);
        let velocity_bandwidth_hz = r.gen_range(50.0..200.0);
        let (ff_velocity, ff_acceleration) = if modern {
            (r.gen_range(0.9..1.0), r.gen_range(0.0..1.0))
        } else {
            (0.0, 0.0)
        };
        let count_um = [0.1, 0.5, 1.0][r.gen_range(0..3)];
        let rho: f64 = r.gen_range(0.3..0.8);
        let noise = ColouredNoise {
            ar1_um: r.gen_range(0.05..0.3),
            ar1_tau_ms: -1e3 / (rate_hz * rho.ln()),
            wander_um: r.gen_range(0.0..0.2),
            vibration_um: r.gen_range(0.0..0.1),
            vibration_hz: r.gen_range(15.0..120.0),
            vibration_bandwidth_hz: 2.0,
        };
        Realistic {
            servo: ServoLoop {
                kv_per_s,
                velocity_bandwidth_hz,
                ff_velocity,
                ff_acceleration,
                count_um,
            },
            noise,
            white_um: r.gen_range(0.05..0.2),
        }
    }

    /// Put these loops and this noise on `config` (its sample rate should be the one drawn for).
    pub fn apply(&self, config: &mut SimConfig) {
        config.errors.dynamics.servo = [Some(self.servo); 3];
        config.instrument.noise_um = self.white_um;
        config.instrument.coloured_noise = self.noise;
    }

    /// One line saying what was drawn, for a test's failure message.
    pub fn describe(&self) -> String {
        let l = &self.servo;
        let n = &self.noise;
        format!(
            "Kv {:.0} s⁻¹, velocity loop {:.0} Hz, feed-forward {:.2}/{:.2}, count {} µm; white \
             {:.2} µm, AR(1) {:.2} µm τ {:.2} ms, wander {:.2} µm, vibration {:.2} µm at {:.0} Hz",
            l.kv_per_s,
            l.velocity_bandwidth_hz,
            l.ff_velocity,
            l.ff_acceleration,
            l.count_um,
            self.white_um,
            n.ar1_um,
            n.ar1_tau_ms,
            n.wander_um,
            n.vibration_um,
            n.vibration_hz
        )
    }
}
