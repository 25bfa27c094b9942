//! Dead-point synthesis: the spindle ball for a *given* table ball, so that the RRSS motion covers
//! a required A range (seed 004 §3.2, §5.1) — the first level of the saddle synthesis
//! ([`super::saddle`]), run on its own.
//!
//! The paper's Table 2 sits on these conditions: with its table ball (s2 = 80 mm, a2 = 30 mm) and
//! d = 300 mm they give back its s0, a0 and θA0 to the printed digits. Four conditions fix the
//! four unknowns s0, a0, θA0, θC0:
//!
//! 1. the rocker's lower dead point (eq. 12-15) is at the required A minimum,
//! 2. its upper dead point is at the required A maximum,
//! 3. the bar length d is the shortest at which C still turns fully (the two branches of eq. 9
//!    meet), so one installation covers the whole range,
//! 4. the lower dead point occurs at C = 0 (this fixes θC0, which does not change the A range).
//!
//! The table ball (s2, a2) and the axes (a1, α12) are taken from the start parameters. Use this
//! when the table ball is fixed by the fixture at hand (`jdbb rrsps synthesize --method
//! dead-point`); the saddle synthesis also chooses the table ball, by the min-max of the ball-cup
//! angles under the constraints g1–g13.
use super::saddle::first_level;
use super::Params;
use crate::{Error, Result};

/// Result of [`synthesize`].
#[derive(Debug, Clone)]
pub struct Synthesis {
    pub params: Params,
    /// Largest residual of the conditions (mm).
    pub max_condition_mm: f64,
}

/// Find s0, a0, θA0, θC0 (starting from `start`; s2, a2, a1, α12 taken from it and held) so that
/// the motion at bar length `d_mm` has its dead points at `a_range_deg`, the lower one at C = 0,
/// and the branches just meeting (see module doc).
pub fn synthesize(start: &Params, d_mm: f64, a_range_deg: [f64; 2]) -> Result<Synthesis> {
    let (params, max_condition_mm) = first_level(start, d_mm, a_range_deg).ok_or_else(|| {
        Error::Numerics(format!(
            "no spindle-ball position near the start puts the rocker's dead points on A {}..{}° with C turning fully at d = {d_mm} mm; start nearer a working design, or change the table ball or d",
            a_range_deg[0].min(a_range_deg[1]),
            a_range_deg[0].max(a_range_deg[1])
        ))
    })?;
    Ok(Synthesis {
        params,
        max_condition_mm,
    })
}
