//! Machine-tool positioning errors and their effect on the ball distance (seed 000, section 3).
//!
//! Conventions (shared with the host's diagnosis): positions in mm relative to the table ball,
//! velocities in mm/s, errors δ in µm, *added* to the nominal spindle-ball position. Seed 000
//! writes each model for the x axis with mixed signs (its eq. 2 vs. 3, 8 vs. 9 disagree on the sign
//! of x); we fix the sign so that a positive parameter lengthens the axis, and the same models
//! apply to y and z.

use crate::math;

/// Seed 000 eq. (1): change of the measured radius (µm) caused by an error vector C = (Cx, Cy, Cz)
/// (µm) at nominal position p (mm): ΔR = (x·Cx + y·Cy + z·Cz) / R. First order in C/R.
pub fn radial_error_um(p_mm: [f64; 3], c_um: [f64; 3]) -> f64 {
    let r = math::sqrt(p_mm[0] * p_mm[0] + p_mm[1] * p_mm[1] + p_mm[2] * p_mm[2]);
    (p_mm[0] * c_um[0] + p_mm[1] * c_um[1] + p_mm[2] * c_um[2]) / r
}

/// The positioning-error models of one axis (seed 000 section 3). All zero means a perfect axis.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct AxisErrors {
    /// First-order uniform contraction (eq. 2): δ = a·k, `a` in µm per metre of travel.
    pub scale_um_per_m: f64,
    /// Second-order contraction (eq. 5): δ = b·k², `b` in µm per m².
    pub scale2_um_per_m2: f64,
    /// Periodic (pitch) error amplitude A (µm) of δ = A·sin(2π·k/p + phase) (eq. 8).
    pub cyclic_um: f64,
    /// Phase of the periodic error (rad).
    pub cyclic_phase_rad: f64,
    /// Interference of detection devices (eq. 11): δ = b·v·sin(2π·k/p + phase), b in µm per mm/s.
    pub interference_um_per_mm_s: f64,
    /// Phase of the interference term (rad).
    pub interference_phase_rad: f64,
    /// Ball-screw or scale pitch p (mm) of the periodic and interference terms.
    pub pitch_mm: f64,
    /// Lost motion (backlash) b (µm), positive = play: the carriage lags its motor by b/2 in the
    /// direction of motion, δ = −b/2 moving +k, +b/2 moving −k (eq. 14 with f = −b). A step,
    /// exact away from a reversal: a real clearance is a dead band taken up over the first b of
    /// travel after it, which the host's models (`model`) evaluate.
    pub backlash_um: f64,
}

impl AxisErrors {
    /// A perfect axis (usable in `const` contexts, unlike `Default`).
    pub const ZERO: AxisErrors = AxisErrors {
        scale_um_per_m: 0.0,
        scale2_um_per_m2: 0.0,
        cyclic_um: 0.0,
        cyclic_phase_rad: 0.0,
        interference_um_per_mm_s: 0.0,
        interference_phase_rad: 0.0,
        pitch_mm: 0.0,
        backlash_um: 0.0,
    };

    /// Positioning error δ (µm) of this axis at nominal coordinate `k_mm`, velocity `v_mm_s` and last
    /// direction of motion `dir` (+1 or −1; holds its sign through a standstill).
    pub fn error_um(&self, k_mm: f64, v_mm_s: f64, dir: i8) -> f64 {
        let k_m = k_mm * 1e-3;
        let mut d = self.scale_um_per_m * k_m + self.scale2_um_per_m2 * k_m * k_m;
        if self.pitch_mm > 0.0 {
            let w = core::f64::consts::TAU * k_mm / self.pitch_mm;
            d += self.cyclic_um * math::sin(w + self.cyclic_phase_rad);
            d +=
                self.interference_um_per_mm_s * v_mm_s * math::sin(w + self.interference_phase_rad);
        }
        d - 0.5 * self.backlash_um * if dir < 0 { -1.0 } else { 1.0 }
    }
}

/// Errors of a three-axis machine: per-axis models plus squareness between axes.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct MachineErrors {
    /// x, y, z axis models.
    pub axes: [AxisErrors; 3],
    /// Squareness xy, yz, zx (µm/m): δ_x += s_xy·y, δ_y += s_yz·z, δ_z += s_zx·x.
    pub squareness_um_per_m: [f64; 3],
}

impl MachineErrors {
    /// Error vector δ (µm) at nominal position `p_mm`, velocity `v_mm_s`, last directions `dir`.
    pub fn error_um(&self, p_mm: [f64; 3], v_mm_s: [f64; 3], dir: [i8; 3]) -> [f64; 3] {
        let mut e = [0.0; 3];
        for k in 0..3 {
            e[k] = self.axes[k].error_um(p_mm[k], v_mm_s[k], dir[k]);
        }
        let s = self.squareness_um_per_m;
        e[0] += s[0] * p_mm[1] * 1e-3;
        e[1] += s[1] * p_mm[2] * 1e-3;
        e[2] += s[2] * p_mm[0] * 1e-3;
        e
    }

    /// Exact distance (mm) between the table ball at the origin and the spindle ball at the
    /// erroneous position p + δ.
    pub fn distance_mm(&self, p_mm: [f64; 3], v_mm_s: [f64; 3], dir: [i8; 3]) -> f64 {
        let e = self.error_um(p_mm, v_mm_s, dir);
        let q = [
            p_mm[0] + e[0] * 1e-3,
            p_mm[1] + e[1] * 1e-3,
            p_mm[2] + e[2] * 1e-3,
        ];
        math::sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn first_order_contraction_matches_eq4() {
        // Seed 000 eq. (4): ΔR = a·x0·cos²θ for δx = a·x on a circle of radius x0 (a = 0.1 µm/mm).
        let m = MachineErrors {
            axes: [
                AxisErrors {
                    scale_um_per_m: 100.0,
                    ..Default::default()
                },
                AxisErrors::default(),
                AxisErrors::default(),
            ],
            ..Default::default()
        };
        let r = 90.0;
        for deg in [0.0f64, 30.0, 45.0, 120.0, 200.0] {
            let th = deg.to_radians();
            let p = [r * th.cos(), r * th.sin(), 0.0];
            let dr_um = (m.distance_mm(p, [0.0; 3], [1; 3]) - r) * 1e3;
            let expect = 0.1 * r * th.cos().powi(2);
            assert!((dr_um - expect).abs() < 1e-3, "{deg}: {dr_um} vs {expect}");
            let lin = radial_error_um(p, m.error_um(p, [0.0; 3], [1; 3]));
            assert!((lin - expect).abs() < 1e-9);
        }
    }

    #[test]
    fn backlash_is_play_minus_half_b_times_cos() {
        // Seed 000 eq. (16) with f = −b: ΔR = ∓(b/2)·cos θ; play makes the axis lag its motion.
        let m = MachineErrors {
            axes: [
                AxisErrors {
                    backlash_um: 10.0,
                    ..Default::default()
                },
                AxisErrors::default(),
                AxisErrors::default(),
            ],
            ..Default::default()
        };
        let p = [50.0 * 0.6, 50.0 * 0.8, 0.0];
        let plus = radial_error_um(p, m.error_um(p, [1.0, 0.0, 0.0], [1, 1, 1]));
        let minus = radial_error_um(p, m.error_um(p, [-1.0, 0.0, 0.0], [-1, 1, 1]));
        assert!((plus + 3.0).abs() < 1e-12 && (minus - 3.0).abs() < 1e-12);
    }

    #[test]
    fn periodic_error_has_its_pitch() {
        let a = AxisErrors {
            cyclic_um: 8.0,
            pitch_mm: 1.0,
            ..Default::default()
        };
        assert!((a.error_um(0.25, 0.0, 1) - 8.0).abs() < 1e-12);
        assert!((a.error_um(1.25, 0.0, 1) - 8.0).abs() < 1e-9);
        assert!(a.error_um(0.5, 0.0, 1).abs() < 1e-9);
    }
}
