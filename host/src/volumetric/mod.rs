//! The volumetric test: all three axes from one table ball (issue 29). With a free radius the
//! spindle ball can run anywhere in a shell about the table ball, so one mount and one program
//! test X, Y and Z together: xy circles at several heights (cones about the ball) and zx and yz
//! 220° arcs through it.
//!
//! - [`ident`]: what such a test can identify of a linear error field — the design matrix of the
//!   three scales, three squarenesses, the set-up offset and the instrument's scale, its rank,
//!   condition number and confounded combinations;
//! - [`fit`]: the linear model's nine terms fitted to changes of D at known positions, with σ
//!   and the undetermined groups (the core of the joint diagnosis);
//! - [`plan`]: the plan of a volumetric test (`jdbb plan --volumetric`), one plan.json
//!   (version [`crate::plan::VOLUMETRIC_VERSION`]) and one program for every dialect,
//!   and the check of a machine's travel.
//!
//! - [`diagnose`]: a volumetric record synchronised across all its elements and diagnosed as one
//!   test (`jdbb diagnose --record --plan` on a volumetric plan), with the scales on the
//!   instrument's calibration, the identifiability beside the record's own rank, and each
//!   plane's G and H.
//!
//! Built: the identifiability, the plan, the linear fit at the plan's positions, the
//! synchronisation and the joint diagnosis. Not yet: the QEMU scenario, the compensation of
//! three squarenesses at once, and the report's picture of the whole test.
//!
//! May use: [`crate::numerics`] and nalgebra, the instrument model (`jdbb_core`), and
//! [`crate::plan`], [`crate::model`], [`crate::sync`], [`crate::diagnose`] and [`crate::report`]
//! by import only (the plane test's plan builder makes each element; its synchronisation and
//! diagnosis run the record). Nothing in those folders uses this module.
pub mod diagnose;
pub mod fit;
pub mod ident;
pub mod plan;
