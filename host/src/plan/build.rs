//! Making a [`Plan`] from a [`PlanSpec`]: the circles, the path of the module docs, and the check
//! that every point the mounted instrument visits keeps D in its range.
use jdbb_core::calib::Calibration;

use super::{
    instrument, line_d_range, ArcRole, Circle, CircleArc, Close, Dialect, Instrument, LineRole,
    Plan, Plane, Purpose, Segment, Sense, FORMAT, GRID_MM, MAX_ARC_DEG, VERSION,
};
use crate::{Error, Result};

/// Default lead-in arc of a full circle (degrees).
pub const DEFAULT_LEAD_IN_DEG: f64 = 180.0;
/// Default overshoot arc of a full circle (degrees).
pub const DEFAULT_OVERSHOOT_DEG: f64 = 180.0;
/// Default arc each circle runs (degrees): a full circle.
pub const DEFAULT_ARC_DEG: f64 = 360.0;
/// Default lead-in and overshoot of a partial arc (degrees), taken from inside the arc: the
/// vertical-plane test's 220° is 20° + 180° of data + 20° (the ballbar makers' partial arc).
pub const PARTIAL_LEAD_IN_DEG: f64 = 20.0;
/// Default overshoot of a partial arc (degrees); see [`PARTIAL_LEAD_IN_DEG`].
pub const PARTIAL_OVERSHOOT_DEG: f64 = 20.0;
/// Default feed-in length (mm).
pub const DEFAULT_FEED_IN_MM: f64 = 2.0;
/// Default dwell (s).
pub const DEFAULT_DWELL_S: f64 = 1.0;
/// Default dwell at the corners next to the feed-in and the feed-out (s): long enough for any
/// controller to stop there (a dwell empties the planner's queue), so the arcs start and end at
/// rest whatever the controller's corner blending (grbl's and Marlin's junction deviation pass a
/// right-angle corner at a few mm/s, which would move the arcs' timeline by milliseconds).
pub const DEFAULT_CORNER_DWELL_S: f64 = 0.1;
/// Every feed-in start is approached along the feed-in's own direction over this length (mm),
/// the take-up: the axes' backlash is taken up and a reversal spike decays (in the dwell) before
/// the feed-in, so that the feed-in's ramp in D — which times the test — carries neither.
pub const TAKE_UP_MM: f64 = 0.5;
/// Largest feed (mm/min).
pub const MAX_FEED_MM_MIN: f64 = 100_000.0;
/// Longest dwell (s).
pub const MAX_DWELL_S: f64 = 600.0;
/// Most lines a move between two circles is split into to keep D in range.
const MAX_MOVE_PIECES: usize = 64;

/// One circle to run: radius and height along the plane's normal (mm), and its own feed in a
/// feed sweep ([`PlanSpec::feed_sweep`]; None: the plan's feed).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CircleSpec {
    pub radius_mm: f64,
    pub height_mm: f64,
    pub feed_mm_min: Option<f64>,
}

/// What `jdbb plan` is asked for (see the module docs for each number's role).
#[derive(Debug, Clone, PartialEq)]
pub struct PlanSpec {
    pub purpose: Purpose,
    /// The circles in execution order.
    pub circles: Vec<CircleSpec>,
    pub plane: Plane,
    pub feed_mm_min: f64,
    /// The table ball's centre in program coordinates.
    pub centre_mm: [f64; 3],
    pub dialect: Dialect,
    /// θ0, where each circle starts and ends (degrees from +i towards +j).
    pub start_deg: f64,
    /// The arc A each circle runs (degrees, 0 < A ≤ 360): 360 a full circle; below, the
    /// machine stays on [θ0, θ0 + A] and the lead-in and overshoot are taken from inside it.
    pub arc_deg: f64,
    pub lead_in_deg: f64,
    pub overshoot_deg: f64,
    pub feed_in_mm: f64,
    /// Dwell before each feed-in and after each feed-out (s; 0: none).
    pub dwell_s: f64,
    /// Dwell at each reversal (s; 0: none).
    pub reversal_dwell_s: f64,
    /// Dwell at the corner after each feed-in and before each feed-out (s; 0: none).
    pub corner_dwell_s: f64,
    /// How the test closes on itself in time: `circles` are run in [`Close::order`].
    pub close: Close,
}

impl PlanSpec {
    /// A machine test with the default tuning: per height, per radius, in the order given.
    pub fn machine_test(
        radii_mm: &[f64],
        heights_mm: &[f64],
        plane: Plane,
        feed_mm_min: f64,
        centre_mm: [f64; 3],
        dialect: Dialect,
    ) -> PlanSpec {
        let circles = machine_test_circles(radii_mm, heights_mm);
        PlanSpec {
            purpose: Purpose::MachineTest,
            circles,
            plane,
            feed_mm_min,
            centre_mm,
            dialect,
            start_deg: 0.0,
            arc_deg: DEFAULT_ARC_DEG,
            lead_in_deg: DEFAULT_LEAD_IN_DEG,
            overshoot_deg: DEFAULT_OVERSHOOT_DEG,
            feed_in_mm: DEFAULT_FEED_IN_MM,
            dwell_s: DEFAULT_DWELL_S,
            reversal_dwell_s: DEFAULT_DWELL_S,
            corner_dwell_s: DEFAULT_CORNER_DWELL_S,
            close: Close::None,
        }
    }

    /// The same test on a partial arc of `arc_deg` from the same start, with the partial arc's
    /// default lead-in and overshoot ([`PARTIAL_LEAD_IN_DEG`], [`PARTIAL_OVERSHOOT_DEG`]) when
    /// `arc_deg` is below 360 (the full circle's otherwise).
    pub fn with_arc(self, arc_deg: f64) -> PlanSpec {
        let (lead_in_deg, overshoot_deg) = default_lead_in_overshoot(arc_deg);
        PlanSpec {
            arc_deg,
            lead_in_deg,
            overshoot_deg,
            ..self
        }
    }

    /// The same circles run once at each of `feeds_mm_min` in turn (all circles at the first
    /// feed, then all at the second, …): a feed sweep, which tells the servo's effects, growing
    /// with feed (the following error, q·v²/R), from mechanical ones, which do not (a scale, a·R).
    /// The plan's own feed becomes the first. One feed leaves the spec as it is.
    pub fn feed_sweep(self, feeds_mm_min: &[f64]) -> PlanSpec {
        let Some(&first) = feeds_mm_min.first() else {
            return self;
        };
        if feeds_mm_min.len() == 1 {
            return PlanSpec {
                feed_mm_min: first,
                ..self
            };
        }
        let circles = feeds_mm_min
            .iter()
            .flat_map(|&f| {
                self.circles.iter().map(move |c| CircleSpec {
                    feed_mm_min: Some(f),
                    ..*c
                })
            })
            .collect();
        PlanSpec {
            circles,
            feed_mm_min: first,
            ..self
        }
    }

    /// The feed of each circle (mm/min): its own in a feed sweep, else the plan's.
    pub fn circle_feed_mm_min(&self, c: &CircleSpec) -> f64 {
        c.feed_mm_min.unwrap_or(self.feed_mm_min)
    }

    /// Whether each circle runs a partial arc (below 360°).
    pub fn is_partial(&self) -> bool {
        self.arc_deg < 360.0
    }

    /// Check the numbers that do not depend on the instrument: feed (0.1 to 100 000 mm/min),
    /// angles (start within ±360°, arc above 0 and at most 360°, lead-in and overshoot 0 to 360°
    /// and, on a partial arc, leaving a data arc inside it), feed-in above 0 and below every
    /// radius, dwells 0 to 600 s, at least one circle. The message names the option.
    pub fn validate(&self) -> Result<()> {
        let usage = |m: String| Err(Error::Usage(m));
        if self.circles.is_empty() {
            return usage("give at least one --radius (or --calibration-test)".into());
        }
        let feeds = self.circles.iter().map(|c| self.circle_feed_mm_min(c));
        for feed in std::iter::once(self.feed_mm_min).chain(feeds) {
            if !(0.1..=MAX_FEED_MM_MIN).contains(&feed) {
                return usage(format!(
                    "--feed {feed}: the feed is 0.1 to {MAX_FEED_MM_MIN} mm/min"
                ));
            }
        }
        if !(-360.0..=360.0).contains(&self.start_deg) {
            return usage(format!(
                "--start-deg {}: the start angle is within ±360°",
                self.start_deg
            ));
        }
        if !(self.arc_deg > 0.0 && self.arc_deg <= 360.0) {
            return usage(format!(
                "--arc-deg {}: the arc each circle runs is above 0° and at most 360° (360: a full circle; 220 from --start-deg -20: the vertical-plane test)",
                self.arc_deg
            ));
        }
        for (name, v) in [
            ("--lead-in-deg", self.lead_in_deg),
            ("--overshoot-deg", self.overshoot_deg),
        ] {
            if !(0.0..=360.0).contains(&v) {
                return usage(format!("{name} {v}: an arc of 0 to 360°"));
            }
        }
        if self.is_partial() && self.lead_in_deg + self.overshoot_deg >= self.arc_deg {
            return usage(format!(
                "--arc-deg {}: on a partial arc the lead-in ({}°) and the overshoot ({}°) are taken from inside the arc and leave no data arc; give a smaller --lead-in-deg or --overshoot-deg, or a longer arc",
                self.arc_deg, self.lead_in_deg, self.overshoot_deg
            ));
        }
        for (name, v) in [
            ("--dwell-s", self.dwell_s),
            ("--reversal-dwell-s", self.reversal_dwell_s),
            ("--corner-dwell-s", self.corner_dwell_s),
        ] {
            if !(0.0..=MAX_DWELL_S).contains(&v) {
                return usage(format!("{name} {v}: a dwell of 0 to {MAX_DWELL_S} s"));
            }
        }
        if !(self.feed_in_mm > 0.0 && self.feed_in_mm.is_finite()) {
            return usage(format!(
                "--feed-in-mm {}: the feed-in is a length above 0 mm",
                self.feed_in_mm
            ));
        }
        if !self
            .centre_mm
            .iter()
            .all(|c| c.is_finite() && c.abs() <= 100_000.0)
        {
            return usage(format!(
                "--centre {:?}: coordinates within ±100000 mm",
                self.centre_mm
            ));
        }
        for c in &self.circles {
            if !(c.radius_mm > 0.0 && c.radius_mm.is_finite() && c.height_mm.is_finite()) {
                return usage(format!(
                    "--radius {} --height {}: a circle needs a radius above 0 and a finite height",
                    c.radius_mm, c.height_mm
                ));
            }
            if c.radius_mm <= self.feed_in_mm {
                return usage(format!(
                    "--radius {}: the feed-in of {} mm starts inside the circle, so the radius is above {} mm (or shorten --feed-in-mm)",
                    c.radius_mm, self.feed_in_mm, self.feed_in_mm
                ));
            }
        }
        Ok(())
    }
}

/// Default (lead-in, overshoot) in degrees for an arc of `arc_deg`: 180° each on a full circle,
/// 20° each (from inside the arc) on a partial arc.
pub fn default_lead_in_overshoot(arc_deg: f64) -> (f64, f64) {
    if arc_deg < 360.0 {
        (PARTIAL_LEAD_IN_DEG, PARTIAL_OVERSHOOT_DEG)
    } else {
        (DEFAULT_LEAD_IN_DEG, DEFAULT_OVERSHOOT_DEG)
    }
}

/// The circles of a machine test: per height, per radius, in the order given.
pub fn machine_test_circles(radii_mm: &[f64], heights_mm: &[f64]) -> Vec<CircleSpec> {
    heights_mm
        .iter()
        .flat_map(|&height_mm| {
            radii_mm.iter().map(move |&radius_mm| CircleSpec {
                radius_mm,
                height_mm,
                feed_mm_min: None,
            })
        })
        .collect()
}

/// Default ball distances of the calibration test: 4 spread evenly from the lowest a sphere can
/// have (its feed-in start at latitude 0 at least 0.5 mm inside D_min) to 10 µm inside D_max.
pub fn default_calibration_distances(inst: &Instrument, feed_in_mm: f64) -> Vec<f64> {
    let lo = inst.d_min_mm + feed_in_mm + 0.5;
    let hi = inst.d_max_mm - 0.01;
    if lo >= hi {
        return vec![q(hi)];
    }
    (0..4).map(|k| q(lo + (hi - lo) * k as f64 / 3.0)).collect()
}

/// The circles of the calibration test: per distance D (in order), circles at
/// [`super::CALIBRATION_LATITUDES_DEG`] — up for the first sphere, down for the next, and so on
/// (R = D cos λ, H = D sin λ).
pub fn calibration_circles(distances_mm: &[f64]) -> Vec<CircleSpec> {
    let mut out = vec![];
    for (k, &d) in distances_mm.iter().enumerate() {
        let mut lat = super::CALIBRATION_LATITUDES_DEG.to_vec();
        if k % 2 == 1 {
            lat.reverse();
        }
        for l in lat {
            let (s, c) = l.to_radians().sin_cos();
            out.push(CircleSpec {
                radius_mm: d * c,
                height_mm: d * s,
                feed_mm_min: None,
            });
        }
    }
    out
}

/// Round to the 1 µm grid ([`GRID_MM`]): a whole number of steps divided by the steps per mm,
/// so the result is the double nearest the decimal the program writes.
pub(crate) fn q(x: f64) -> f64 {
    let per_mm = (1.0 / GRID_MM).round();
    let r = (x * per_mm).round() / per_mm;
    if r == 0.0 {
        0.0 // no -0.0 in files
    } else {
        r
    }
}

fn q3(p: [f64; 3]) -> [f64; 3] {
    p.map(q)
}

/// The plan for `spec` on the instrument `cal`: the path of the module docs, refused (usage
/// error, exit 2) if any D the mounted instrument would reach is outside its range.
pub fn plan(spec: &PlanSpec, cal: &Calibration) -> Result<Plan> {
    spec.validate()?;
    let inst = instrument(cal)?;
    let (i, j, n) = spec.plane.axes();
    let centre = q3(spec.centre_mm);
    let round_feed = |f: f64| (f * 1000.0).round() / 1000.0;
    let plan_feed = round_feed(spec.feed_mm_min);
    let f = spec.feed_in_mm;
    let dwell = (spec.dwell_s * 1000.0).round() / 1000.0;
    let reversal_dwell = (spec.reversal_dwell_s * 1000.0).round() / 1000.0;
    let corner_dwell = (spec.corner_dwell_s * 1000.0).round() / 1000.0;
    let theta0 = spec.start_deg;
    let mut u = [0.0; 3];
    (u[j], u[i]) = theta0.to_radians().sin_cos();
    let mut circles = vec![];
    let mut segments = vec![];
    let mut previous_in: Option<[f64; 3]> = None;
    for (k, cs) in spec.close.order(&spec.circles).iter().enumerate() {
        let (r, h) = (q(cs.radius_mm), q(cs.height_mm));
        let feed = round_feed(spec.circle_feed_mm_min(cs));
        check_circle(&inst, k, r, h, f + TAKE_UP_MM)?;
        let mut c = centre;
        c[n] = q(c[n] + h);
        let point = |deg: f64, radius: f64| {
            let (s, co) = deg.to_radians().sin_cos();
            let mut p = c;
            p[i] += radius * co;
            p[j] += radius * s;
            q3(p)
        };
        let p_in = point(theta0, r - f);
        let p_take_up = point(theta0, r - f - TAKE_UP_MM);
        // A partial arc's ends move only inwards: the machine never leaves [θ0, θ0 + A].
        let bounds = if spec.is_partial() {
            (theta0, theta0 + spec.arc_deg)
        } else {
            (f64::NEG_INFINITY, f64::INFINITY)
        };
        let on_circle = |deg: f64| on_circle(c, (i, j), r, deg, bounds);
        let (p0, theta0_on) = on_circle(theta0);
        circles.push(Circle {
            index: k,
            radius_mm: r,
            height_mm: h,
            centre_mm: c,
            d_mm: (r * r + h * h).sqrt(),
            plane: spec.plane,
            feed_mm_min: feed,
            arc: None,
        });
        match previous_in {
            None => {
                segments.push(Segment::Rapid {
                    from_mm: p_take_up,
                    to_mm: p_take_up,
                });
                segments.push(Segment::Stop);
            }
            Some(from) => {
                let waypoints = move_path(&inst, &centre, (u, n), from, p_take_up).ok_or_else(|| {
                    Error::Usage(format!(
                        "cannot move from circle {k} to circle {} keeping D within {}; give the circles in another order",
                        k + 1,
                        inst.describe()
                    ))
                })?;
                let mut a = from;
                for b in waypoints {
                    segments.push(Segment::Line {
                        from_mm: a,
                        to_mm: b,
                        feed_mm_min: feed,
                        role: LineRole::Move,
                        circle: k,
                    });
                    a = b;
                }
            }
        }
        segments.push(Segment::Line {
            from_mm: p_take_up,
            to_mm: p_in,
            feed_mm_min: feed,
            role: LineRole::Move,
            circle: k,
        });
        if dwell > 0.0 {
            segments.push(Segment::Dwell { seconds: dwell });
        }
        segments.push(Segment::Line {
            from_mm: p_in,
            to_mm: p0,
            feed_mm_min: feed,
            role: LineRole::FeedIn,
            circle: k,
        });
        if corner_dwell > 0.0 {
            segments.push(Segment::Dwell {
                seconds: corner_dwell,
            });
        }
        let mut arcs = Arcs {
            circle: k,
            centre: c,
            radius: r,
            plane: spec.plane,
            feed,
            nominal_deg: theta0,
            at_deg: theta0_on,
            at: p0,
            on_circle: &on_circle,
            out: &mut segments,
        };
        let span = circle_arc(spec);
        let (lead, data, over) = (span.lead_in_deg, span.data_sweep_deg, span.overshoot_deg);
        arcs.sweep(lead, ArcRole::LeadIn);
        arcs.sweep(data, ArcRole::Data);
        arcs.sweep(over, ArcRole::Overshoot);
        if reversal_dwell > 0.0 {
            arcs.out.push(Segment::Dwell {
                seconds: reversal_dwell,
            });
        }
        if spec.is_partial() {
            // Back over the same arc: the ccw overshoot is the cw lead-in, the ccw lead-in the
            // cw overshoot, so the machine never leaves [θ0, θ0 + A].
            arcs.sweep(-over, ArcRole::LeadIn);
            arcs.sweep(-data, ArcRole::Data);
            arcs.sweep(-lead, ArcRole::Overshoot);
        } else {
            arcs.sweep(-lead, ArcRole::LeadIn);
            arcs.sweep(-data, ArcRole::Data);
            arcs.sweep(-over, ArcRole::Overshoot);
        }
        let end = arcs.at;
        if corner_dwell > 0.0 {
            segments.push(Segment::Dwell {
                seconds: corner_dwell,
            });
        }
        segments.push(Segment::Line {
            from_mm: end,
            to_mm: p_in,
            feed_mm_min: feed,
            role: LineRole::FeedOut,
            circle: k,
        });
        if dwell > 0.0 {
            segments.push(Segment::Dwell { seconds: dwell });
        }
        previous_in = Some(p_in);
    }
    let start_mm = segments[0].to_mm().expect("the first segment is the rapid");
    let plan = Plan {
        format: FORMAT.into(),
        version: VERSION,
        purpose: spec.purpose,
        program: spec.dialect.program_name().into(),
        dialect: spec.dialect,
        units: "mm".into(),
        plane: spec.plane,
        centre_mm: centre,
        feed_mm_min: plan_feed,
        instrument: inst,
        start_mm,
        arc: circle_arc(spec),
        close: spec.close,
        circles,
        segments,
    };
    check_range(&plan)?;
    Ok(plan)
}

/// The arc each circle of `spec` runs, with its lead-in, data arc and overshoot (degrees; the
/// start angle as given, not wrapped).
fn circle_arc(spec: &PlanSpec) -> CircleArc {
    let (theta0, lead, over) = (spec.start_deg, spec.lead_in_deg, spec.overshoot_deg);
    if spec.is_partial() {
        CircleArc {
            start_deg: theta0,
            sweep_deg: spec.arc_deg,
            lead_in_deg: lead,
            overshoot_deg: over,
            data_start_deg: theta0 + lead,
            data_sweep_deg: spec.arc_deg - lead - over,
        }
    } else {
        CircleArc {
            start_deg: theta0,
            sweep_deg: 360.0,
            lead_in_deg: lead,
            overshoot_deg: over,
            data_start_deg: theta0 + lead,
            data_sweep_deg: 360.0,
        }
    }
}

/// Refuse a circle (0-based `k`) whose D or feed-in start is outside the range, naming the range
/// and the radii that fit at its height.
fn check_circle(inst: &Instrument, k: usize, r: f64, h: f64, f: f64) -> Result<()> {
    let d = (r * r + h * h).sqrt();
    let d_in = ((r - f) * (r - f) + h * h).sqrt();
    if inst.contains(d) && inst.contains(d_in) {
        return Ok(());
    }
    let what = if inst.contains(d) {
        format!("its feed-in, with the take-up before it, starts {f} mm inside, at D = {d_in:.3} mm, which")
    } else {
        format!("D = √(R² + H²) = {d:.3} mm")
    };
    let r_lo = (inst.d_min_mm * inst.d_min_mm - h * h).max(0.0).sqrt() + f;
    let r_hi = (inst.d_max_mm * inst.d_max_mm - h * h).max(0.0).sqrt();
    let fits = if h.abs() < inst.d_max_mm && r_lo <= r_hi {
        format!("at height {h} mm the radius can be {r_lo:.3}..{r_hi:.3} mm")
    } else {
        format!("no circle fits at height {h} mm")
    };
    Err(Error::Usage(format!(
        "circle {} (radius {r} mm, height {h} mm): {what} is outside the instrument's range {}; {fits}",
        k + 1,
        inst.describe()
    )))
}

/// The way-points (after `from`, ending at `to`) of a move between two feed-in starts keeping D
/// in range: a straight line if it does, else lines through points spaced evenly in D and in
/// elevation along the half-plane at the start angle that both points lie in (unit û in the
/// circle's plane, normal axis `n`), with as few pieces as keep every line in range. `None` if
/// 64 pieces do not.
fn move_path(
    inst: &Instrument,
    c: &[f64; 3],
    (u, n): ([f64; 3], usize),
    from: [f64; 3],
    to: [f64; 3],
) -> Option<Vec<[f64; 3]>> {
    let in_range = |a: &[f64; 3], b: &[f64; 3]| {
        let (lo, hi) = line_d_range(c, a, b);
        inst.contains(lo) && inst.contains(hi)
    };
    if in_range(&from, &to) {
        return Some(vec![to]);
    }
    // (D, elevation) of a point c + ρ·û + η·n̂.
    let polar = |p: &[f64; 3]| {
        let rho: f64 = (0..3).map(|k| (p[k] - c[k]) * u[k]).sum();
        let eta = p[n] - c[n];
        (rho.hypot(eta), eta.atan2(rho))
    };
    let ((d0, e0), (d1, e1)) = (polar(&from), polar(&to));
    for pieces in 2..=MAX_MOVE_PIECES {
        let mut pts: Vec<[f64; 3]> = (1..pieces)
            .map(|s| {
                let t = s as f64 / pieces as f64;
                let (d, e) = (d0 + t * (d1 - d0), e0 + t * (e1 - e0));
                let mut p: [f64; 3] = std::array::from_fn(|k| c[k] + d * e.cos() * u[k]);
                p[n] += d * e.sin();
                q3(p)
            })
            .collect();
        pts.push(to);
        let mut prev = from;
        let ok = pts.iter().all(|p| {
            let ok = in_range(&prev, p);
            prev = *p;
            ok
        });
        if ok {
            return Some(pts);
        }
    }
    None
}

/// Appends the arcs of one circle, split into pieces of at most [`MAX_ARC_DEG`].
/// The arcs of one circle as they are added: where the path stands on the circle (`at`, a grid
/// point, at the angle `at_deg`) and where it would stand without the grid (`nominal_deg`), so
/// that the grid never adds up along the arcs.
struct Arcs<'a, F: Fn(f64) -> ([f64; 3], f64)> {
    circle: usize,
    centre: [f64; 3],
    radius: f64,
    plane: Plane,
    feed: f64,
    nominal_deg: f64,
    at_deg: f64,
    at: [f64; 3],
    on_circle: &'a F,
    out: &'a mut Vec<Segment>,
}

impl<F: Fn(f64) -> ([f64; 3], f64)> Arcs<'_, F> {
    fn sweep(&mut self, sweep_deg: f64, role: ArcRole) {
        if sweep_deg == 0.0 {
            return;
        }
        let pieces = (sweep_deg.abs() / MAX_ARC_DEG - 1e-9).ceil().max(1.0) as usize;
        let step = sweep_deg / pieces as f64;
        for _ in 0..pieces {
            let nominal_end = self.nominal_deg + step;
            let (to, end_deg) = (self.on_circle)(nominal_end);
            let sweep = step + (end_deg - nominal_end) - (self.at_deg - self.nominal_deg);
            self.out.push(Segment::Arc {
                circle: self.circle,
                centre_mm: self.centre,
                radius_mm: self.radius,
                plane: self.plane,
                sense: if step > 0.0 { Sense::Ccw } else { Sense::Cw },
                start_deg: self.at_deg.rem_euclid(360.0),
                sweep_deg: sweep,
                feed_mm_min: self.feed,
                role,
                from_mm: self.at,
                to_mm: to,
            });
            self.nominal_deg = nominal_end;
            self.at_deg = end_deg;
            self.at = to;
        }
    }
}

/// How far (deg) an arc's end may move along its circle to a grid point on the circle.
pub const ON_CIRCLE_SEARCH_DEG: f64 = 0.5;
/// A grid point this close to the circle (nm) is on it: about the J-DBB's count (10 nm), a
/// fiftieth of its noise. Within ±0.5° of any angle there is one on circles of 12.5 to 150 mm
/// (the worst found: 12 nm; ±0.2° left 234 nm near 45°, where the grid's columns round alike).
pub const ON_CIRCLE_NM: f64 = 15.0;

/// The point of the 1 µm grid within [`ON_CIRCLE_SEARCH_DEG`] of the angle `deg` (from axis i
/// towards axis j) and within `bounds` (deg, on the turn of `deg`) on the circle of radius `r`
/// about `c` (a grid point) that lies closest to the circle, and its angle (deg, near `deg`). An arc's ends on the grid but off its
/// circle make every controller draw something else: LinuxCNC and Fanuc a spiral from the start
/// radius to the end radius, grbl and Marlin the start radius and a step at the end. Rounded
/// where the angle says, an end is up to 0.71 µm off the circle (0.25 µm at −110° on R 90 mm),
/// which the ballbar sees as a radius changing along the arc; among the ~R·0.012 grid columns of
/// the search one lies within [`ON_CIRCLE_NM`] of it (the nearest the angle asked for of those).
/// Multiples of 90° are exact points and stay.
pub(crate) fn on_circle(
    c: [f64; 3],
    (i, j): (usize, usize),
    r: f64,
    deg: f64,
    bounds: (f64, f64),
) -> ([f64; 3], f64) {
    let per_mm = (1.0 / GRID_MM).round();
    let r_g = r * per_mm; // radius in grid steps (a whole number: r is on the grid)
    let (s, co) = deg.to_radians().sin_cos();
    let half = ON_CIRCLE_SEARCH_DEG.to_radians();
    // Step along the axis the circle crosses the faster there, solve for the other.
    let along_i = s.abs() > co.abs();
    let (lo, hi) = {
        let (a0, a1) = ((deg.to_radians() - half), (deg.to_radians() + half));
        let f = |a: f64| {
            if along_i {
                r_g * a.cos()
            } else {
                r_g * a.sin()
            }
        };
        let (u, v) = (f(a0), f(a1));
        (u.min(v).ceil() as i64, u.max(v).floor() as i64)
    };
    let mut best: Option<(f64, f64, f64, f64)> = None; // (radius error, angle error, a, b)
    for m in lo..=hi {
        let m = m as f64;
        let other = (r_g * r_g - m * m).max(0.0).sqrt();
        let other = if along_i {
            other * s.signum()
        } else {
            other * co.signum()
        };
        let (a, b) = if along_i {
            (m, other.round())
        } else {
            (other.round(), m)
        };
        let err = (a.hypot(b) - r_g).abs();
        let ang = b.atan2(a).to_degrees();
        let signed = (ang - deg + 180.0).rem_euclid(360.0) - 180.0;
        let d_ang = signed.abs();
        let at = deg + signed;
        if d_ang > ON_CIRCLE_SEARCH_DEG + 1e-9 || at < bounds.0 - 1e-9 || at > bounds.1 + 1e-9 {
            continue;
        }
        // Among the points within ON_CIRCLE_NM of the circle the one nearest the angle asked
        // for; without one, the nearest the circle.
        let good = |e: f64| e <= ON_CIRCLE_NM * 1e-6 * per_mm;
        let better = match best {
            None => true,
            Some((e, d, _, _)) => match (good(err), good(e)) {
                (true, true) => d_ang < d,
                (true, false) => true,
                (false, true) => false,
                (false, false) => err < e,
            },
        };
        if better {
            best = Some((err, d_ang, a, b));
        }
    }
    let (a, b) = match best {
        Some((_, _, a, b)) => (a, b),
        // No grid column in the search (a circle of a few µm): the rounded point.
        None => ((r_g * co).round(), (r_g * s).round()),
    };
    let mut p = c;
    p[i] = q(c[i] + a / per_mm);
    p[j] = q(c[j] + b / per_mm);
    let ang = b.atan2(a).to_degrees();
    // The angle as near `deg` as it is (not wrapped to another turn).
    let ang = deg + ((ang - deg + 180.0).rem_euclid(360.0) - 180.0);
    (p, ang)
}

/// Every mounted segment (all after the stop) keeps D in range. A guard on the construction
/// above.
pub(crate) fn check_range(plan: &Plan) -> Result<()> {
    let inst = &plan.instrument;
    for k in 2..plan.segments.len() {
        if let Some((lo, hi)) = plan.d_range_mm(k) {
            if !(inst.contains(lo) && inst.contains(hi)) {
                return Err(Error::Usage(format!(
                    "segment {k} of the plan reaches D = {lo:.3}..{hi:.3} mm, outside the instrument's range {}",
                    inst.describe()
                )));
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_arc_end_is_a_grid_point_on_its_circle_near_its_angle() {
        let c = [100.0, 50.0, -20.0];
        let mut worst_nm = 0.0f64;
        for r in [12.5, 40.0, 85.0, 90.0, 91.357, 150.0] {
            for k in 0..720 {
                let deg = -180.0 + 0.5 * k as f64 + 0.123;
                let (p, ang) = on_circle(c, (0, 2), r, deg, (f64::NEG_INFINITY, f64::INFINITY));
                // On the grid, in the plane, on the circle, near the angle asked for.
                for x in p {
                    assert!((x * 1000.0 - (x * 1000.0).round()).abs() < 1e-6, "{p:?}");
                }
                assert_eq!(p[1], c[1]);
                let (di, dj) = (p[0] - c[0], p[2] - c[2]);
                let err_nm = (di.hypot(dj) - r).abs() * 1e6;
                worst_nm = worst_nm.max(err_nm);
                assert!(
                    (ang - deg).abs() <= ON_CIRCLE_SEARCH_DEG + 1e-9,
                    "{deg} → {ang}"
                );
                assert!((dj.atan2(di).to_degrees() - ang).abs() < 1e-9);
            }
        }
        // Rounded where the angle says, ends were up to 0.71 µm off.
        assert!(worst_nm <= ON_CIRCLE_NM, "{worst_nm} nm");
        // Multiples of 90° are grid points and stay; bounds keep an end inside them.
        let (p, ang) = on_circle(c, (0, 2), 90.0, 90.0, (f64::NEG_INFINITY, f64::INFINITY));
        assert_eq!((p, ang), ([100.0, 50.0, 70.0], 90.0));
        let (_, ang) = on_circle(c, (0, 2), 90.0, -20.0, (-20.0, 200.0));
        assert!(
            (-20.0..=-20.0 + ON_CIRCLE_SEARCH_DEG).contains(&ang),
            "{ang}"
        );
        let (_, ang) = on_circle(c, (0, 2), 90.0, 200.0, (-20.0, 200.0));
        assert!(
            (200.0 - ON_CIRCLE_SEARCH_DEG..=200.0).contains(&ang),
            "{ang}"
        );
    }
}
