//! A simulated circular test (ISO 230-4 style): the spindle ball circles the table ball
//! counter-clockwise, then clockwise, for ever; machine errors from [`crate::machine`] displace it,
//! and the instrument model turns the true distance into the encoder counts the J-DBB would read.
//! The model is the extended one of [`crate::geometry`], so a simulated instrument with errors
//! (bar lengths, zeros, eccentricity, skew, tilts, pivot offsets in [`CircularTest::cal`]) reads
//! the counts such an instrument would.
//!
//! The QEMU build of the firmware feeds these counts through the same sample path as real encoders,
//! so everything downstream of the counter registers is exercised as on the real board.

use crate::calib::Calibration;
use crate::geometry;
use crate::machine::MachineErrors;
use crate::math;

/// A circle in the machine's XY plane around the table ball, run ccw then cw.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CircularTest {
    /// Nominal radius = nominal ball distance (mm).
    pub radius_mm: f64,
    /// Feed along the path (mm/min).
    pub feed_mm_min: f64,
    /// Machine errors added to the nominal spindle-ball position.
    pub errors: MachineErrors,
    /// The instrument that reads the distance.
    pub cal: Calibration,
}

/// The state of the simulated machine at one instant.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pose {
    /// Nominal spindle-ball position (mm).
    pub p_mm: [f64; 3],
    /// Nominal velocity (mm/s).
    pub v_mm_s: [f64; 3],
    /// True ball distance including machine errors (mm).
    pub d_mm: f64,
    /// Angle of the nominal position on the circle (rad).
    pub theta_rad: f64,
}

impl CircularTest {
    /// The default test of the QEMU demo: R = 90 mm with the default instrument
    /// ([`Calibration::DEFAULT`]: 50 mm + 50 mm, 2²³ counts/rev; deflection ≈ 52°, inside the
    /// frames' range), 1000 mm/min (seed 000 §4), no machine errors.
    pub const DEFAULT: CircularTest = CircularTest {
        radius_mm: 90.0,
        feed_mm_min: 1000.0,
        errors: MachineErrors {
            axes: [crate::machine::AxisErrors::ZERO; 3],
            squareness_um_per_m: [0.0; 3],
        },
        cal: Calibration::DEFAULT,
    };

    /// Duration of one full circle (µs).
    pub fn circle_period_us(&self) -> f64 {
        core::f64::consts::TAU * self.radius_mm / (self.feed_mm_min / 60.0) * 1e6
    }

    /// Where the machine is at time `t_us` after the start: first circle ccw from θ = 0, second cw
    /// back to θ = 0, repeating.
    pub fn pose_at(&self, t_us: u64) -> Pose {
        let period = self.circle_period_us();
        let cycle = 2.0 * period;
        let t = t_us as f64 % cycle;
        let w = core::f64::consts::TAU / period * 1e6; // rad/s
        let (theta, sense) = if t < period {
            (core::f64::consts::TAU * t / period, 1.0)
        } else {
            (core::f64::consts::TAU * (1.0 - (t - period) / period), -1.0)
        };
        let (s, c) = math::sin_cos(theta);
        let r = self.radius_mm;
        let p = [r * c, r * s, 0.0];
        let v = [-r * w * s * sense, r * w * c * sense, 0.0];
        // Direction of the last motion of each axis, which holds through a standstill (at a
        // reversal v_k = 0): take it from the velocity an instant earlier.
        let (s_prev, c_prev) = math::sin_cos(theta - sense * 1e-6);
        let dir = [sign(-s_prev * sense), sign(c_prev * sense), 1];
        Pose {
            p_mm: p,
            v_mm_s: v,
            d_mm: self.errors.distance_mm(p, v, dir),
            theta_rad: theta,
        }
    }

    /// Extended encoder counts the J-DBB reads at `t_us`, bar 2 leaning towards the spindle's
    /// azimuth. `None` if the radius is outside the instrument's reach.
    pub fn counts_at(&self, t_us: u64) -> Option<(i64, i64)> {
        let pose = self.pose_at(t_us);
        geometry::counts_for_distance(&self.cal, pose.d_mm, pose.theta_rad)
    }
}

fn sign(v: f64) -> i8 {
    if v < 0.0 {
        -1
    } else {
        1
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::machine::AxisErrors;

    #[test]
    fn ideal_machine_reads_the_radius_to_one_count() {
        let t = CircularTest::DEFAULT;
        let k = geometry::Kernel::new(&t.cal);
        let period = t.circle_period_us() as u64;
        for i in 0..200u64 {
            let t_us = i * period / 100; // two circles
            let (c1, c2) = t.counts_at(t_us).unwrap();
            let s = geometry::sensitivity_mm_per_count(&t.cal, c1, c2);
            let tol = 0.5 * (s[0].abs() + s[1].abs()) + 1e-6;
            assert!((k.distance_mm(c1, c2) - 90.0).abs() <= tol);
        }
    }

    #[test]
    fn instrument_errors_are_in_the_simulated_counts() {
        // An instrument with hidden errors: its own calibration reads the ideal circle back to a
        // count; the nominal instrument's model is off by micrometres (what calibration removes).
        const ARCSEC: f64 = core::f64::consts::PI / 180.0 / 3600.0;
        let mut t = CircularTest::DEFAULT;
        t.cal.enc2.zero_offset_rad = 60.0 * ARCSEC;
        t.cal.axes_skew_rad = 90.0 * ARCSEC;
        t.cal.enc1.eccentricity_rad = 40.0 * ARCSEC;
        t.cal.frame2.tilt_rad = -50.0 * ARCSEC;
        t.cal.validate().unwrap();
        let own = geometry::Kernel::new(&t.cal);
        let nominal = geometry::Kernel::new(&Calibration::DEFAULT);
        let period = t.circle_period_us() as u64;
        let (mut worst_own, mut worst_nominal) = (0.0f64, 0.0f64);
        for i in 0..100u64 {
            let (c1, c2) = t.counts_at(i * period / 100).unwrap();
            worst_own = worst_own.max((own.distance_mm(c1, c2) - 90.0).abs());
            worst_nominal = worst_nominal.max((nominal.distance_mm(c1, c2) - 90.0).abs());
        }
        assert!(worst_own < 5e-5, "{worst_own}");
        assert!(worst_nominal > 3e-3, "{worst_nominal}");
    }

    #[test]
    fn runs_ccw_then_cw() {
        let t = CircularTest::DEFAULT;
        let q = t.circle_period_us() as u64 / 4;
        let a = t.pose_at(q);
        let b = t.pose_at(5 * q);
        assert!((a.theta_rad - core::f64::consts::FRAC_PI_2).abs() < 1e-6);
        assert!((b.theta_rad - 3.0 * core::f64::consts::FRAC_PI_2).abs() < 1e-6);
        assert!(a.v_mm_s[0] < 0.0); // ccw at 90°: moving −x
        assert!(b.v_mm_s[0] < 0.0); // cw at 270°: moving −x too
        let speed = (a.v_mm_s[0].powi(2) + a.v_mm_s[1].powi(2)).sqrt();
        assert!((speed - 1000.0 / 60.0).abs() < 1e-9);
    }

    #[test]
    fn backlash_shows_in_counts() {
        let mut t = CircularTest::DEFAULT;
        t.cal.enc1.counts_per_rev = 1 << 22;
        t.cal.enc2.counts_per_rev = 1 << 22;
        t.errors.axes[0] = AxisErrors {
            backlash_um: 20.0,
            ..AxisErrors::ZERO
        };
        let k = geometry::Kernel::new(&t.cal);
        // Play of 20 µm: the carriage lags its motion by 10 µm. At θ = 180° (moving −y, x = −R,
        // last x motion −x): δx = +10 µm → D shorter by 10 µm.
        let half = t.circle_period_us() as u64 / 2;
        let (c1, c2) = t.counts_at(half).unwrap();
        let d = k.distance_mm(c1, c2);
        assert!((d - 89.990).abs() < 2e-4, "{d}");
    }
}
