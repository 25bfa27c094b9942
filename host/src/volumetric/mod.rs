//! The volumetric test: all three axes from one table ball (issue 29). With a free radius the
//! spindle ball can run anywhere in a shell about the table ball, so one mount and one program
//! test X, Y and Z together: xy circles at several heights (cones about the ball) and zx and yz
//! 220° arcs through it.
//!
//! - [`ident`]: what such a test can identify of a linear error field — the design matrix of the
//!   three scales, three squarenesses, the set-up offset and the instrument's scale, its rank,
//!   condition number and confounded combinations;
//! - [`elements`]: how long the machine stays on each element of a plan (a record cut into its
//!   elements);
//! - [`fit`]: the linear model's nine terms fitted to changes of D at known positions, with σ
//!   and the undetermined groups (the core of the joint diagnosis);
//! - [`plan`]: the plan of a volumetric test (`jdbb plan --volumetric`), one plan.json
//!   (version [`crate::plan::VOLUMETRIC_VERSION`]) and one program for every dialect,
//!   and the check of a machine's travel.
//!
//! Built: the identifiability, the plan, and the linear fit at the plan's positions. Not yet: the
//! synchronisation of a volumetric record and its joint diagnosis with backlash, servo and
//! cyclic terms (`jdbb diagnose --record --plan` refuses a volumetric plan) and the report.
//!
//! May use: [`crate::numerics`] and nalgebra, the instrument model (`jdbb_core`), and
//! the plan and path types of [`crate::plan`] and [`crate::model`] by import only (the plane
//! test's plan builder makes each element). Nothing in those folders uses this module.
pub mod elements;
pub mod fit;
pub mod ident;
pub mod plan;

use std::path::Path;

use crate::plan::{Plan, Purpose};
use crate::{Error, Result};

/// Refuse to diagnose a record of a volumetric plan (read from `plan_file`) as a plane test: its
/// joint diagnosis is not built yet, and a plane test's fit would name the wrong axes.
pub fn refuse_diagnosis(plan: &Plan, plan_file: &Path) -> Result<()> {
    if plan.purpose != Purpose::VolumetricTest {
        return Ok(());
    }
    Err(Error::Usage(format!(
        "{} is a volumetric test (cones and arcs of several planes): volumetric diagnosis is not built yet; keep the record, and diagnose plane tests (jdbb plan --plane) meanwhile",
        plan_file.display()
    )))
}
