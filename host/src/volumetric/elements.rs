//! A volumetric record synchronised across all its elements: each element of the plan (an xy
//! cone at its height, a zx or yz arc in its plane) found in one record from D alone, with its
//! start and its feed.
//!
//! Every element is one of the plan's circles, entered by its own radial feed-in from a dwell and
//! left by its feed-out, and the moves along the shell between elements keep D away from the
//! next element's level until its feed-in. So the plane test's synchronisation
//! ([`crate::sync::synchronise`]) finds each element in turn, as it finds the circles of a plane
//! test: the plan's 3-D segments carry each cone's height and each arc's plane, which give the
//! levels of D to look for and the nominal position of every data sample
//! ([`crate::sync::data_path`]). [`elements`] states what it found per element.
//!
//! Not built yet: the joint diagnosis. The plane diagnosis's selection run over all elements'
//! data at once is wrong (measured on the G-code machine with errors on all three axes: its
//! angles, runs and partial-arc rules are those of one main plane, so the arcs fall into hundreds
//! of "circles" and most effects go unnamed), so `jdbb diagnose` still refuses a volumetric plan.
//!
//! May use: [`crate::sync`], [`crate::plan`] and this module's siblings.
use crate::plan::{Plan, Plane};
use crate::sync::Sync;

use super::plan::element_kind;

/// One element of a volumetric record as the synchronisation found it.
#[derive(Debug, Clone, PartialEq)]
pub struct Element {
    /// The plan's circle (0-based).
    pub circle: usize,
    /// `xy cone`, `zx arc`, … ([`element_kind`]).
    pub kind: String,
    pub plane: Plane,
    /// Along the plane's normal from the table ball (mm).
    pub height_mm: f64,
    pub radius_mm: f64,
    /// The feed-in's start on the record's clock (s).
    pub start_s: f64,
    /// The feed the element ran at (mm/min, on the record's clock) and as programmed.
    pub feed_mm_min: f64,
    pub programmed_feed_mm_min: f64,
    /// Data-arc samples of the element.
    pub samples: usize,
}

/// Each element of `plan` in the record as `sync` found it, in program order.
pub fn elements(plan: &Plan, sync: &Sync) -> Vec<Element> {
    sync.circles
        .iter()
        .map(|c| {
            let pc = &plan.circles[c.circle];
            Element {
                circle: c.circle,
                kind: element_kind(plan, c.circle),
                plane: pc.plane,
                height_mm: pc.height_mm,
                radius_mm: pc.radius_mm,
                start_s: c.feed_in.profile.t0_s,
                feed_mm_min: 60.0 * c.speed_mm_s,
                programmed_feed_mm_min: pc.feed_mm_min,
                samples: c.data.iter().map(|a| a.samples).sum(),
            }
        })
        .collect()
}
