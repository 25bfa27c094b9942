//! What a diagnosis says, for people and for programs: the text summary and the documented JSON.
//! (The polar plot is [`crate::report::plot`].)
//!
//! # Digits
//! Every figure printed for people (text, `report.html`, plots) is rounded to what its σ
//! supports: two significant digits of σ, the value to the same decimal place
//! ([`crate::units::format_estimate`], [`crate::units::format_to`]). A fitted value and its
//! parameters use their own standard error; G, H, peak-to-valley and RMS figures use the test's
//! noise, the residual RMS (`final.rms_um`); a residual harmonic's amplitude uses
//! noise·√(2/samples). The JSON keeps every number unrounded.
//!
//! # One G
//! A test has one circular deviation G per circle and direction: the radial width of the minimum
//! zone of that trace (ISO 230-4 with the minimum-zone centre, [`crate::diagnose::zone`]). Text, JSON,
//! `report.html` and the plots all show that G; the test's G is the largest of them. Beside it,
//! the filtered G: the same of the trace low-passed at 50 undulations per revolution
//! ([`crate::diagnose::zone`], *Filter*), which the instrument's noise does not inflate.
//!
//! # One centre
//! The fitted set-up (`setup_offset`, `length_offset`: where the table ball is relative to where
//! it was assumed, and the bar's length offset) is the one centre: the text says it once as the
//! move that centres the ball, the plotted traces have it removed, the zone centres are given
//! from it. The least-squares centre of all samples (`lsq_setup`, which ISO 230-4's F is about)
//! and the minimum-zone centres are details (`--verbose`, the JSON): an effect's first harmonic
//! (backlash, servo mismatch) moves them, not the fitted set-up.
//!
//! # Shares
//! Two shares, named plainly everywhere (text, JSON, `report.html`):
//! - **share of G** (`g_share`): how much of the test's circular deviation G the effect makes,
//!   (G − G without it) / G, where *G without it* (`g_without_um`) is the largest minimum-zone G
//!   of the measured traces with the radial deviation the effect alone makes taken out; at
//!   least 0. It is what a ballbar user reads a percentage as: what G would lose if the effect
//!   were fixed. A reversal spike that sets G has a share of G even where its mean square is
//!   nothing; an effect the zone's centring takes up (a first harmonic) has none. Shares of G
//!   do not add up to 100 %: G is a peak-to-valley, and two effects can each set much of it.
//! - **mean-square share** (`share`, `residual_share`): the mean square of the radial deviation
//!   the effect alone makes (its own least-squares centring removed), over the sum of that of
//!   every machine effect and the mean square of the residual (`final.rms_um`²). These add up to
//!   1; printed as whole percentages they are rounded by largest remainder so that they add up
//!   to exactly 100 % ([`crate::units::percentages`]). Correlated effects share some of their
//!   deviation, which this sum counts once per effect: it says how large an effect is against
//!   the others over the whole trace.
//!
//! Effects are listed by share of G, largest first, then by mean-square share
//! ([`rank_order`]), in the text and in `report.html`.
//!
//! # Signs
//! - `backlash_k`: positive = lost motion (play) at reversal, negative = the axis runs ahead
//!   (over-compensation);
//! - `setup_offset`, `lsq_setup`, the zone centres: where the table ball is relative to where it
//!   was assumed (the same sign as `jdbb calibrate`'s table-ball offset).
//!
//! Files written before these conventions (no `format`, or `format` 1) are upgraded when read
//! ([`crate::report::document`]).
//!
//! # JSON (`--json`, and `diagnosis.json` in `--report DIR`)
//! ```text
//! format                   2: the conventions above (absent in older files: 1)
//! samples                  number of samples used
//! baseline.rms_um          RMS of D − |p| (ideal machine), µm
//! baseline.pv_um           peak-to-valley of D − |p|, µm
//! effects[]                set-up first (setup_offset, length_offset), then machine effects in
//!                          the order the selection added them
//!   .name                  effect name (setup_offset, length_offset, scale_k, scale2_k,
//!                          backlash_k, cyclic_k, interference_k, squareness_ij,
//!                          servo_mismatch_ij, or the identifiable scale_mismatch_ij)
//!   .value                 |c| for setup_offset, amplitude for cyclic/interference, else the
//!                          single parameter; from the exact-geometry refit
//!   .unit                  um, um/m, um/m^2, um/(mm/s), ms, um/min or um/m/min
//!   .sigma                 standard error of value (delta method), null if undetermined
//!   .params                {parameter: value}: setup_offset {x_um,y_um,z_um}, length_offset
//!                          {e_um}, scale/scale_mismatch {a_um_per_m}, scale2 {b_um_per_m2},
//!                          backlash {b_um: the lost motion; pos_um, neg_um: at the reversal
//!                          at the + and − end of the travel, when they differ}, cyclic
//!                          {sin_um,cos_um}
//!                          (A·sin(w+φ) = sin_um·sin w + cos_um·cos w, w = 2πk/pitch),
//!                          interference {sin_um_per_mm_s, cos_um_per_mm_s}, squareness
//!                          {s_um_per_m}, servo_mismatch {dtau_ms: how much later the first
//!                          axis follows its command than the second, lag_ms: their common
//!                          lag}, reversal_spike {h_um: height, tau_ms: decay time}, drift
//!                          {rate_um_per_min}, scale_drift_k {rate_um_per_m_per_min: the
//!                          thermal drift of k's scale}, position_drift_k {rate_um_per_min}
//!   .params_sigma          {parameter: standard error or null (undetermined, held at 0)}
//!   .rms_after_um          RMS of the residual after the step that added this effect (linear
//!                          search); for the set-up, after the set-up fit
//!   .rms_ratio             RMS before / after that step
//!   .delta_bic             change of the Bayesian information criterion by that step (the
//!                          evidence the selection weighed; negative = better; null for the
//!                          set-up)
//!   .setup                 true for setup_offset and length_offset
//!   .cause                 the cause in the trade's words, what to check or set
//!                          ([`crate::model::words`])
//! confounded[][]           groups of names the test cannot tell apart (effects, or set-up
//!                          components setup_offset.x/.y/.z); a group of one is a parameter the
//!                          path does not excite at all
//! floor_um                 the reporting floor: an effect that changes D by less than this
//!                          anywhere is not named (µm)
//! below_floor[]            {name, peak_um}: effects the data support but that stay under the
//!                          floor (peak_um bounds their largest contribution to D)
//! not_significant[]        {name, value, sigma, unit, params, reason}: effects the selection
//!                          chose that the data cannot carry, not named: parameters not
//!                          determined, a spike decaying within one sample period, or a value
//!                          within 2σ of zero once σ counts the timing uncertainty; and an
//!                          interference that is a named cyclic error read where its lagging
//!                          axis is (kept in the model, named as part of the cyclic error)
//! final.rms_um             RMS of the residual of the exact refit, µm (the test's noise)
//! residual_share           the residual's mean-square share (see *Shares*)
//! gain                     baseline.rms_um / final.rms_um
//! noise_tau_int            how many samples of the residual make one independent sample (its
//!                          integrated autocorrelation time; 1 = white noise). Above 2 the
//!                          selection counted samples / noise_tau_int and every σ is
//!                          √noise_tau_int larger than a white-noise fit's
//! radius_loss[]            where following_error is named: {radius_mm, feed_mm_min, loss_um,
//!                          sigma_um} for each circle at each speed it ran (a feed sweep runs
//!                          one radius at several): the radius the loops take off it, q·v²/R
//! harmonics_um[]           amplitude of residual harmonics 1..8 against the angle in the plane
//!                          of the two axes with the largest travel, µm
//! lsq_setup                {x_um, y_um, z_um, e_um}: the least-squares set-up of all samples,
//!                          D ≈ |p − t| + e, t = where the table ball is relative to where it
//!                          was assumed: a detail, the centre ISO 230-4's F is about (the
//!                          plot removes the fitted set-up, see *One centre*)
//! circular_deviation_g_um  the test's G: the largest minimum-zone G of a circle in one
//!                          direction (= minimum_zone.g_um), µm
//! hysteresis_h_um          the test's H: the largest H of a circle (= minimum_zone.h_um), µm
//! g_if_compensated_um      what-if: the test's G with the named effects a controller setting
//!                          removes (backlash, scale, squareness, cyclic error; a reversal spike
//!                          with a machine profile's Heidenhain; each ≥ 3σ, as `jdbb compensate`
//!                          acts on them) taken out of the measured traces, µm
//! pitch_hint               null, or without --pitch where the residual is above its noise
//!                          and one pitch stands out in it against an axis' position
//!                          (`diagnose::pitch_hint`): {axis, pitch_mm, amplitude_um}, the pitch
//!                          to try with --pitch (a cyclic error may be unmodelled)
//! lsq_circular_deviation_g_um  only in files upgraded from format 1: their G about the
//!                          least-squares centre, kept (not written by this version)
//! candidates[]             the candidate effects that were tried
//! arcs[]                   per circle (as `circles`): {start_deg, sweep_deg, partial}, the arc
//!                          its samples cover in the plane, degrees from the plane's first axis
//!                          (360 a full circle); on a partial arc `harmonics_um` is empty
//! weak_on_arc[]            on a partial arc, {names, free_fraction}: a candidate (first) whose
//!                          shape is its own by less than 1 % (free_fraction) beside the set-up
//!                          components and scales named after it; tried, and where one of them
//!                          is named the others are its alternative. A candidate with nothing of
//!                          its own is not tried and is in `confounded`
//! ```
//!
//! Added for acting on a diagnosis (issue 10); every field is optional to a reader, so a file
//! written before them still reads ([`crate::report::document`]):
//!
//! ```text
//! effects[].contribution_rms_um  RMS of the radial deviation the effect alone makes, with its
//!                          own least-squares centring removed, µm (null for the set-up)
//! effects[].share          the effect's mean-square share (see *Shares*; null for the set-up)
//! effects[].g_share        the effect's share of G (see *Shares*; null for the set-up)
//! effects[].g_without_um   the test's G with the effect's deviation taken out, µm
//! circular_deviation_g_filtered_um  the test's G of the traces low-passed at filter_upr, µm
//! filter_upr               the low-pass cut-off, undulations per revolution (50)
//! circles[].g_filtered_um  {ccw, cw}: G of that trace low-passed at filter_upr, µm (null: not
//!                          run)
//! plane                    xy, yz or zx: the plane of the two axes with the largest travel; the
//!                          polar angle is measured from the first axis towards the second
//! pitch_mm                 {x, y, z}: the pitch per axis the diagnosis was given, mm or null
//! circles[]                per circle (radius, height) of the path:
//!   .radius_mm, .height_mm nominal radius in the plane and height along its normal, mm
//!   .feed_mm_min           median speed of the nominal path over the circle, mm/min
//!   .samples               samples of the circle (both directions)
//!   .g_um                  ISO 230-4 circular deviation G with the minimum-zone centre: the
//!                          larger of .ccw.g_um and .cw.g_um, µm
//!   .h_um                  hysteresis H: largest ccw − cw difference in a 1° bin, µm
//!   .radial_deviation_f    ISO 230-4 radial deviation F per direction, {ccw, cw}: {max_um,
//!                          min_um} (null if not run), the largest and smallest deviation of
//!                          the path from the nominal circle about the least-squares centre,
//!                          the radius as the calibrated bar measures it
//!                          ([`radial_deviation_f`])
//!   .ccw, .cw, .bidirectional  the minimum zone of that trace (null if not run): {g_um (zone
//!                          width), centre {<axis>_um, <axis>_um} (the minimum-zone centre as
//!                          a table-ball position relative to where it was assumed, along the
//!                          plane's axes: comparable with lsq_setup and setup_offset),
//!                          radius_offset_um}
//! minimum_zone             {g_um, h_um}: the largest G and H over the circles
//!
//! Written by `jdbb diagnose` from its options, when given:
//! machine                  --machine NAME
//! date_utc                 --date, else the time of the diagnosis (RFC 3339, UTC)
//! date_of                  what date_utc is the date of: `test` (--date) or `diagnosis`
//! tolerance                {g_um, pass}: --tolerance-um and whether every circle's G is within it
//! calibration              --calibration FILE: the instrument calibration (jdbb-core Calibration)
//! calibration_file         --calibration FILE: its name, as given
//! plan                     the test plan, when the diagnosis was given one (read as an opaque
//!                          object by the report and the history)
//! operator                 --operator NAME
//! temperature_c            {machine, instrument}: --machine-temperature-c,
//!                          --instrument-temperature-c (°C; null if not given)
//! table_ball_mm            {x, y, z}: --table-ball, machine coordinates (G53) of the table ball
//!                          during the test, mm (null for an axis not given)
//! compensation             {text, file}: the compensation in force during the test,
//!                          --compensation TEXT or --compensation-file FILE (its text)
//! instrument               {serial}: the instrument's serial number, from the record's
//!                          `# instrument_serial:` header line (as the device reported it)
//! ```
//!
//! The folder `report/`: this module writes a diagnosis (text, JSON); [`plot`] draws it (polar
//! plot, SVG and PNG); [`document`] reads that JSON back (the input contract of compensation and
//! history); [`html`] is the report a person reads (`report.html`), [`pdf`] the same page
//! printed. May use: [`crate::model`], [`crate::plan`], [`crate::sync`], [`crate::diagnose`],
//! [`crate::numerics`], [`crate::units`]; the highest of the test folders.
// Index loops over the axes (k in 0..3) and samples mirror the equations; keep them.
pub mod document;
pub mod html;
pub mod pdf;
pub mod plot;
mod timing;
use crate::diagnose::zone::CircleZone;
use crate::diagnose::Diagnosis;
use crate::model::words::{cause, param_text};
use crate::model::{Effect, Pair};
use crate::numerics::mzc::MinimumZone;
use crate::plan::{Plan, Sense};
use crate::report::document::FORMAT;
use crate::sync::Sync;
use crate::units::{format_estimate, format_to, percentages};
pub use timing::*;

/// What a technician reads of a diagnosis (the default text of `jdbb diagnose`): where the table
/// ball is and how to move it, the machine effects ranked by their share of G (see *Shares*)
/// with the cause in the trade's words, what the test cannot tell apart among what it named,
/// and G and H of every circle, raw and filtered. Nothing about an effect that was not named:
/// that, and the figures of the method, are in [`details`]. Every figure is shown to the digits
/// its σ supports (module docs, *Digits*).
pub fn summary(d: &Diagnosis) -> String {
    use std::fmt::Write;
    let mut s = String::new();
    let um = |x: f64| format_to(x, d.final_rms_um);
    let _ = writeln!(s, "{} samples", d.samples);
    let _ = writeln!(s, "{}", centring_text(d));
    let shares = share_percentages(d);
    let g_shares = g_share_percentages(d);
    let machine = ranked(d);
    if machine.is_empty() {
        let _ = writeln!(s, "no machine effect is supported by the data");
    }
    for (rank, &i) in machine.iter().enumerate() {
        let f = &d.effects[i];
        let pct = |p: Option<u32>| p.map_or("–".to_string(), |p| format!("{p} %"));
        let _ = writeln!(
            s,
            "{}. {} = {} {}{}: {} of G, {} of the mean square — {}",
            rank + 1,
            f.effect.name(),
            format_estimate(f.value, f.sigma),
            crate::units::human(f.effect.unit()),
            match f.effect {
                Effect::Squareness(pair) =>
                    format!(" ({})", squareness_angle(pair, f.value, f.sigma)),
                _ => String::new(),
            },
            pct(g_shares[i]),
            pct(shares.effects[i]),
            cause(f.effect, f.value)
        );
        if f.params.len() > 1 {
            let _ = writeln!(s, "    {}", params_text(f));
        }
        if f.effect == Effect::FollowingError {
            let _ = writeln!(s, "    {}", radius_loss_text(d, f.value));
        }
    }
    let named: Vec<String> = machine
        .iter()
        .map(|&i| d.effects[i].effect.name())
        .collect();
    for g in d
        .confounded
        .iter()
        .filter(|g| g.iter().any(|n| named.contains(n)))
    {
        let _ = writeln!(s, "{}", confounded_text(g));
    }
    if let Some(p) = shares.residual.filter(|_| !machine.is_empty()) {
        let _ = writeln!(
            s,
            "residual: RMS {} µm, {p} % of the mean square — noise and what no effect explains",
            um(d.final_rms_um)
        );
    }
    let normal = ['x', 'y', 'z'][3 - d.plane.0 - d.plane.1];
    for (k, c) in d.circle_zones.iter().enumerate() {
        let raw = |z: &Option<crate::numerics::mzc::MinimumZone>| z.map(|z| z.width_um);
        let filtered = d.filtered_g_um.get(k).copied().unwrap_or([None, None]);
        let g = |g: Option<f64>| g.map_or("not run".to_string(), |g| format!("{} µm", um(g)));
        let _ = writeln!(
            s,
            "circle {} (r {:.1} mm, {normal} {:.1} mm): G ccw {}, cw {}; H {} µm; filtered G ccw {}, cw {}",
            k + 1,
            c.radius_mm,
            c.height_mm,
            g(raw(&c.ccw)),
            g(raw(&c.cw)),
            um(c.h_um),
            g(filtered[0]),
            g(filtered[1]),
        );
    }
    if !d.circle_zones.is_empty() {
        let _ = writeln!(
            s,
            "G: circular deviation (ISO 230-4, minimum zone) of the raw trace, the test's; H: hysteresis; filtered: the trace low-passed at {:.0} undulations per revolution, which takes out the instrument's noise",
            d.filter_upr
        );
    }
    if d.g_if_compensated_um != d.circular_deviation_g_um {
        let _ = writeln!(s, "{}", what_if_text(d));
    }
    if let Some(h) = &d.pitch_hint {
        let _ = writeln!(
            s,
            "the residual is above its noise and repeats every {:.1} mm of {} travel ({} µm): a cyclic (screw pitch) error may be unmodelled — diagnose again with --pitch {}={:.1}",
            h.pitch_mm,
            h.axis.letter().to_ascii_uppercase(),
            um(h.amplitude_um),
            h.axis.letter(),
            h.pitch_mm
        );
    }
    let partial = partial_arcs(d);
    if !partial.is_empty() {
        let _ = writeln!(
            s,
            "partial arc: {}; the set-up and scale are less sure than on a full circle (their σ says by how much)",
            partial.join(", ")
        );
        for w in d.weak_on_arc.iter().filter(|w| named.contains(&w.names[0])) {
            let _ = writeln!(s, "{}", weak_text(w));
        }
    }
    s
}

/// The details of a diagnosis behind `jdbb diagnose --verbose`: the ideal machine, the set-up
/// with its σ and the other centres (least-squares, minimum zone), each selection step's RMS,
/// gain and BIC, every group the test cannot tell apart, what was tried and not named and why,
/// the residual's harmonics and noise, and on a partial arc what it barely tells apart.
pub fn details(d: &Diagnosis) -> String {
    use std::fmt::Write;
    let mut s = String::new();
    let noise = d.final_rms_um;
    let um = |x: f64| format_to(x, noise);
    let _ = writeln!(
        s,
        "ideal machine (D = |p|): RMS {} µm, peak-to-valley {} µm",
        um(d.baseline_rms_um),
        um(d.baseline_pv_um)
    );
    for (i, f) in d.effects.iter().enumerate() {
        let step = if i < 2 {
            "set-up".to_string()
        } else {
            format!("selection step {}", i - 1)
        };
        let _ = writeln!(
            s,
            "{step}: {} = {} {}{}",
            f.effect.name(),
            format_estimate(f.value, f.sigma),
            crate::units::human(f.effect.unit()),
            if i >= 1 {
                format!(
                    "; RMS after {} µm, gain ×{:.2}{}",
                    um(f.rms_after_um),
                    f.rms_ratio,
                    if f.delta_bic.is_finite() {
                        format!(", ΔBIC {:.0}", f.delta_bic)
                    } else {
                        String::new()
                    }
                )
            } else {
                String::new()
            }
        );
        if f.params.len() > 1 {
            let _ = writeln!(s, "    {}", params_text(f));
        }
        if f.effect == crate::model::Effect::FollowingError {
            let _ = writeln!(s, "    {}", radius_loss_text(d, f.value));
        }
        if !f.effect.is_setup() && f.g_without_um.is_finite() {
            let _ = writeln!(
                s,
                "    G without it {} µm (of {} µm); RMS of its deviation alone {} µm",
                um(f.g_without_um),
                um(d.circular_deviation_g_um),
                um(f.contribution_rms_um)
            );
        }
    }
    let l = ['x', 'y', 'z'];
    let (a, b) = d.plane;
    let _ = writeln!(
        s,
        "least-squares centre of all samples (ISO 230-4's F is about it): table ball at {} {} µm, {} {} µm; length offset {} µm",
        l[a],
        um(d.lsq_setup_um[a]),
        l[b],
        um(d.lsq_setup_um[b]),
        um(d.lsq_setup_um[3])
    );
    let fitted = d.fitted_setup_um();
    for (k, c) in d.circle_zones.iter().enumerate() {
        for (dir, z) in [("ccw", &c.ccw), ("cw", &c.cw)] {
            if let Some(z) = z {
                let _ = writeln!(
                    s,
                    "minimum-zone centre, circle {} {dir}: table ball at {} {} µm, {} {} µm",
                    k + 1,
                    l[a],
                    um(fitted[a] - z.centre_um[0]),
                    l[b],
                    um(fitted[b] - z.centre_um[1])
                );
            }
        }
    }
    for g in &d.confounded {
        let _ = writeln!(
            s,
            "confounded (this test cannot tell apart): {}",
            g.join(", ")
        );
    }
    for (name, peak) in &d.below_floor {
        let _ = writeln!(
            s,
            "below the floor (significant, but at most {peak:.3} µm on D, under {:.3} µm): {name} — not named",
            d.floor_um
        );
    }
    for w in &d.not_significant {
        let params: Vec<String> = w
            .params
            .iter()
            .enumerate()
            .map(|(k, (n, v))| {
                param_text(
                    n,
                    *v,
                    w.params_sigma.get(k).copied().flatten(),
                    "undetermined",
                )
            })
            .collect();
        let _ = writeln!(
            s,
            "not named: {} = {} {} ({}) — {}",
            w.name,
            format_estimate(w.value, Some(w.sigma_value)),
            crate::units::human(w.unit),
            params.join(", "),
            w.reason
        );
    }
    let _ = writeln!(
        s,
        "final: RMS {} µm, gain ×{:.2} over the ideal machine",
        um(d.final_rms_um),
        d.gain,
    );
    if d.noise_tau_int > crate::diagnose::CORRELATED_TAU {
        let _ = writeln!(
            s,
            "noise: correlated, {:.1} samples make one independent sample: the selection and every \
             σ count {} of the {} samples",
            d.noise_tau_int,
            (d.samples as f64 / d.noise_tau_int).round(),
            d.samples
        );
    }
    if partial_arcs(d).is_empty() {
        // A harmonic's amplitude from m samples of noise σ has a standard error of about
        // σ·√(2/m).
        let harmonic_sigma = noise * (2.0 / d.samples.max(1) as f64).sqrt();
        let h: Vec<String> = d
            .harmonics_um
            .iter()
            .enumerate()
            .map(|(k, a)| format!("{}:{}", k + 1, format_to(*a, harmonic_sigma)))
            .collect();
        let _ = writeln!(s, "residual harmonics vs angle (order:µm): {}", h.join(" "));
    } else {
        let _ = writeln!(
            s,
            "residual harmonics are not shown on a partial arc (they need the whole circle)"
        );
        for w in &d.weak_on_arc {
            let _ = writeln!(s, "{}", weak_text(w));
        }
    }
    s
}

/// The one centre, in words a technician acts on: where the fitted set-up puts the table ball
/// relative to where it was assumed, and the move that centres it (the components the path
/// determines; to 0.1 µm, a machine's step).
fn centring_text(d: &Diagnosis) -> String {
    let t = d.fitted_setup_um();
    let held = d
        .effects
        .first()
        .map(|f| f.param_sigma.clone())
        .unwrap_or_default();
    let axes: Vec<usize> = (0..3)
        .filter(|&k| held.get(k).copied().flatten().is_some() && t[k].abs() >= 0.05)
        .collect();
    if axes.is_empty() {
        return "set-up: the table ball is where it was assumed (within 0.1 µm); the set-up is removed from everything below".into();
    }
    let list = |sign: f64| -> String {
        axes.iter()
            .map(|&k| format!("{:+.1} µm in {}", sign * t[k], ['X', 'Y', 'Z'][k]))
            .collect::<Vec<_>>()
            .join(", ")
    };
    format!(
        "set-up: the table ball sits {} from where it was assumed — to centre it, move the table ball {} (or the program's centre {}); the set-up is removed from everything below, it is not a machine error",
        list(1.0),
        list(-1.0),
        list(1.0)
    )
}

/// The parameters of a found effect for people, `label value ± σ unit`, comma-separated.
fn params_text(f: &crate::diagnose::Found) -> String {
    f.effect
        .param_names()
        .iter()
        .zip(&f.params)
        .zip(&f.param_sigma)
        .map(|((n, v), s)| param_text(n, *v, *s, "undetermined, held"))
        .collect::<Vec<_>>()
        .join(", ")
}

/// A group the test cannot tell apart, in plain words with what separates them: a second radius
/// for the scales and the bar's length, and for a bow and a second-order scale (x² = R² − y² on
/// one circle; the constant R² differs per circle, docs/mechanisms.md).
fn confounded_text(group: &[String]) -> String {
    let radius = |n: &String| {
        ["scale", "length_offset", "straightness"]
            .iter()
            .any(|p| n.starts_with(p))
    };
    let remedy = if group.iter().any(radius) {
        "run a second radius about the same table ball"
    } else {
        "run another radius or plane"
    };
    match group.split_last() {
        Some((last, first)) if !first.is_empty() => format!(
            "this test cannot tell {} from {last}: {remedy} to separate them",
            first.join(", ")
        ),
        _ => format!(
            "this test does not measure {}: the path does not move it; {remedy} to measure it",
            group.join(", ")
        ),
    }
}

/// A candidate a partial arc barely tells from others, as the text says it.
fn weak_text(w: &crate::diagnose::WeakOnArc) -> String {
    format!(
        "weak on this arc: only {:.2} % of {}'s shape is its own beside {} (its σ some {:.0} times that of a shape of its own): where one of them is named, the others are its alternative",
        100.0 * w.free_fraction,
        w.names[0],
        w.names[1..].join(", "),
        1.0 / w.free_fraction.sqrt()
    )
}

/// The partial arcs of a diagnosis, each as `circle k covers …° (a° to b° from x towards y)`.
fn partial_arcs(d: &Diagnosis) -> Vec<String> {
    d.arcs
        .iter()
        .enumerate()
        .filter(|(_, a)| a.is_partial())
        .map(|(k, a)| {
            // From −180° up, so an arc across the first axis reads −20° to 200°.
            let start = if a.start_deg > 180.0 {
                a.start_deg - 360.0
            } else {
                a.start_deg
            };
            format!(
                "circle {} covers {:.0}° ({:.0}° to {:.0}° from {} towards {})",
                k + 1,
                a.sweep_deg,
                start,
                start + a.sweep_deg,
                ["x", "y", "z"][d.plane.0],
                ["x", "y", "z"][d.plane.1]
            )
        })
        .collect()
}

/// The included angle of a pair's axes for a squareness `s` µm/m (δ_i = s·j: i moves s per
/// metre of j travel, so +j leans towards +i for s > 0 and the angle between +i and +j is
/// 90° − atan(s·10⁻⁶)), e.g. `+X and +Y at 89.99857°, acute`; to the digits its σ supports.
pub fn squareness_angle(pair: Pair, s_um_per_m: f64, sigma: Option<f64>) -> String {
    let (i, j) = pair.axes();
    let angle_deg = 90.0 - (1e-6 * s_um_per_m).atan().to_degrees();
    let sigma_deg = sigma.map(|s| (1e-6 * s).to_degrees());
    let kind = if angle_deg < 90.0 {
        "acute"
    } else if angle_deg > 90.0 {
        "obtuse"
    } else {
        "square"
    };
    let up = |a: crate::model::Axis| a.letter().to_ascii_uppercase();
    format!(
        "+{} and +{} at {}°, {kind}",
        up(i),
        up(j),
        match sigma_deg.filter(|s| s.is_finite() && *s > 0.0) {
            Some(sd) => format_to(angle_deg, sd),
            None => format!("{angle_deg:.5}"),
        }
    )
}

/// The machine effects of a diagnosis (indices into [`Diagnosis::effects`]) in the order every
/// output lists them ([`rank_order`]).
pub fn ranked(d: &Diagnosis) -> Vec<usize> {
    let keys: Vec<Option<(f64, f64)>> = d
        .effects
        .iter()
        .map(|f| (!f.effect.is_setup()).then(|| (g_share(d, f), f.share)))
        .collect();
    rank_order(&keys)
}

/// The order effects are listed in (text, `report.html`): by share of G, largest first, then by
/// mean-square share (an effect that does not move G, e.g. a scale on a circle whose zone
/// takes it up, still has a mean square); `None` (the set-up) is left out. Returns indices.
pub fn rank_order(shares: &[Option<(f64, f64)>]) -> Vec<usize> {
    let key = |x: f64| if x.is_finite() { x } else { 0.0 };
    let mut idx: Vec<usize> = (0..shares.len()).filter(|&i| shares[i].is_some()).collect();
    idx.sort_by(|&a, &b| {
        let (ga, ma) = shares[a].expect("filtered");
        let (gb, mb) = shares[b].expect("filtered");
        key(gb)
            .total_cmp(&key(ga))
            .then(key(mb).total_cmp(&key(ma)))
    });
    idx
}

/// An effect's share of G (see *Shares*): how much of the test's G it makes, (G − G without
/// it) / G, at least 0; NaN for the set-up or where G is 0.
pub fn g_share(d: &Diagnosis, f: &crate::diagnose::Found) -> f64 {
    let g = d.circular_deviation_g_um;
    if f.effect.is_setup() || g.is_nan() || g <= 0.0 {
        return f64::NAN;
    }
    ((g - f.g_without_um) / g).max(0.0)
}

/// The shares of G as whole percentages, per effect of [`Diagnosis::effects`] (None for the
/// set-up). They do not add up to 100: two effects can each set much of G.
pub fn g_share_percentages(d: &Diagnosis) -> Vec<Option<u32>> {
    d.effects
        .iter()
        .map(|f| {
            let s = g_share(d, f);
            s.is_finite().then(|| (100.0 * s).round() as u32)
        })
        .collect()
}

/// The shares of the error as whole percentages that add up to 100 (largest remainder, see
/// [`percentages`]): per effect of [`Diagnosis::effects`] (None for the set-up) and the residual.
pub struct SharePercentages {
    pub effects: Vec<Option<u32>>,
    pub residual: Option<u32>,
}

/// [`SharePercentages`] of a diagnosis.
pub fn share_percentages(d: &Diagnosis) -> SharePercentages {
    let shares: Vec<Option<f64>> = d
        .effects
        .iter()
        .map(|f| (!f.effect.is_setup()).then_some(f.share))
        .collect();
    split_percentages(&shares, d.residual_share)
}

/// Whole percentages of the machine effects' shares (None: the set-up, no share) and the
/// residual's, adding up to 100.
pub fn split_percentages(shares: &[Option<f64>], residual: f64) -> SharePercentages {
    let mut flat: Vec<f64> = shares.iter().flatten().copied().collect();
    flat.push(residual);
    if !flat.iter().any(|x| x.is_finite() && *x > 0.0) {
        return SharePercentages {
            effects: vec![None; shares.len()],
            residual: None,
        };
    }
    let pct = percentages(&flat);
    let mut it = pct.iter().copied();
    let effects = shares.iter().map(|s| s.and_then(|_| it.next())).collect();
    SharePercentages {
        effects,
        residual: it.next(),
    }
}

/// The documented JSON (see the README): samples, baseline, effects, confounded, final, gain.
pub fn to_json(d: &Diagnosis) -> serde_json::Value {
    use serde_json::{json, Map, Value};
    let num = |x: f64| if x.is_finite() { json!(x) } else { Value::Null };
    let effects: Vec<Value> = d
        .effects
        .iter()
        .map(|f| {
            let mut params = Map::new();
            let mut psig = Map::new();
            for ((n, v), s) in f
                .effect
                .param_names()
                .iter()
                .zip(&f.params)
                .zip(&f.param_sigma)
            {
                params.insert((*n).into(), num(*v));
                psig.insert((*n).into(), s.map(num).unwrap_or(Value::Null));
            }
            json!({
                "name": f.effect.name(),
                "value": num(f.value),
                "unit": f.effect.unit(),
                "sigma": f.sigma.map(num).unwrap_or(Value::Null),
                "params": params,
                "params_sigma": psig,
                "rms_after_um": num(f.rms_after_um),
                "rms_ratio": num(f.rms_ratio),
                "delta_bic": num(f.delta_bic),
                "setup": f.effect.is_setup(),
                "cause": cause(f.effect, f.value),
            })
        })
        .collect();
    let mut v = json!({
        "format": FORMAT,
        "samples": d.samples,
        "baseline": {"rms_um": num(d.baseline_rms_um), "pv_um": num(d.baseline_pv_um)},
        "effects": effects,
        "confounded": d.confounded,
        "floor_um": num(d.floor_um),
        "below_floor": d.below_floor.iter().map(|(n, p)| json!({"name": n, "peak_um": num(*p)})).collect::<Vec<_>>(),
        "not_significant": d.not_significant.iter().map(|w| json!({
            "name": w.name, "value": num(w.value), "sigma": num(w.sigma_value), "unit": w.unit,
            "params": w.params.iter().map(|(n, v)| (n.to_string(), num(*v))).collect::<serde_json::Map<_, _>>(),
            "reason": w.reason,
        })).collect::<Vec<_>>(),
        "final": {"rms_um": num(d.final_rms_um)},
        "residual_share": num(d.residual_share),
        "gain": num(d.gain),
        "noise_tau_int": num(d.noise_tau_int),
        "radius_loss": d.radius_loss.iter().map(|l| json!({
            "radius_mm": num(l.radius_mm), "feed_mm_min": num(l.feed_mm_min),
            "loss_um": num(l.loss_um), "sigma_um": l.sigma_um.map(num),
        })).collect::<Vec<_>>(),
        "harmonics_um": d.harmonics_um,
        "lsq_setup": {
            "x_um": num(d.lsq_setup_um[0]),
            "y_um": num(d.lsq_setup_um[1]),
            "z_um": num(d.lsq_setup_um[2]),
            "e_um": num(d.lsq_setup_um[3]),
        },
        "circular_deviation_g_um": num(d.circular_deviation_g_um),
        "hysteresis_h_um": num(d.hysteresis_h_um),
        "g_if_compensated_um": num(d.g_if_compensated_um),
        "pitch_hint": d.pitch_hint.as_ref().map(|h| json!({
            "axis": h.axis.letter().to_string(),
            "pitch_mm": num(h.pitch_mm),
            "amplitude_um": num(h.amplitude_um),
        })),
        "candidates": d.candidates,
        "arcs": d.arcs.iter().map(|a| json!({
            "start_deg": num(a.start_deg), "sweep_deg": num(a.sweep_deg), "partial": a.is_partial(),
        })).collect::<Vec<_>>(),
        "weak_on_arc": d.weak_on_arc.iter().map(|w| json!({
            "names": w.names, "free_fraction": num(w.free_fraction),
        })).collect::<Vec<_>>(),
    });
    add_zones_and_shares(&mut v, d);
    v
}

/// The what-if line: the G with the compensable settings entered, beside the measured G.
fn what_if_text(d: &Diagnosis) -> String {
    let um = |x: f64| format_to(x, d.final_rms_um);
    format!(
        "G with the compensable settings entered (jdbb compensate): {} µm (measured {} µm)",
        um(d.g_if_compensated_um),
        um(d.circular_deviation_g_um)
    )
}

/// The plane's name (`xy`, `yz`, `zx`) for the axis pair `plane`.
pub fn plane_name(plane: (usize, usize)) -> String {
    let l = ['x', 'y', 'z'];
    format!("{}{}", l[plane.0], l[plane.1])
}

/// The issue 10 fields of the JSON (see the module docs): effect shares, plane, pitch, circles
/// with their conditions and minimum-zone G and H.
fn add_zones_and_shares(v: &mut serde_json::Value, d: &Diagnosis) {
    use serde_json::{json, Value};
    let num = |x: f64| if x.is_finite() { json!(x) } else { Value::Null };
    if let Some(effects) = v["effects"].as_array_mut() {
        for (e, f) in effects.iter_mut().zip(&d.effects) {
            e["contribution_rms_um"] = num(f.contribution_rms_um);
            e["share"] = num(f.share);
            e["g_share"] = num(g_share(d, f));
            e["g_without_um"] = num(f.g_without_um);
        }
    }
    let axes = ['x', 'y', 'z'];
    let (a, b) = d.plane;
    let zone = |z: &Option<MinimumZone>| match z {
        None => Value::Null,
        Some(z) => {
            // The zone's centre as a table-ball position, relative to where it was assumed: the
            // fitted set-up's t (removed from the traces), moved by the zone centre. A trace
            // centred at z in the plot (deviation ≈ z·u) is a table ball displaced by −z
            // (D ≈ |p| − u·t).
            let fitted = d.fitted_setup_um();
            let mut centre = serde_json::Map::new();
            centre.insert(format!("{}_um", axes[a]), num(fitted[a] - z.centre_um[0]));
            centre.insert(format!("{}_um", axes[b]), num(fitted[b] - z.centre_um[1]));
            json!({"g_um": num(z.width_um), "centre": centre, "radius_offset_um": num(z.radius_offset_um)})
        }
    };
    let f = radial_deviation_f(d);
    let f_json = |r: &Option<(f64, f64)>| match r {
        Some((max, min)) => json!({"max_um": num(*max), "min_um": num(*min)}),
        None => Value::Null,
    };
    let circles: Vec<Value> = d
        .circle_zones
        .iter()
        .enumerate()
        .map(|(k, c): (usize, &CircleZone)| {
            let [ccw, cw] = f.get(k).copied().unwrap_or([None, None]);
            let [g_ccw, g_cw] = d.filtered_g_um.get(k).copied().unwrap_or([None, None]);
            json!({
                "g_filtered_um": {"ccw": g_ccw.map(num), "cw": g_cw.map(num)},
                "radial_deviation_f": {"ccw": f_json(&ccw), "cw": f_json(&cw)},
                "radius_mm": num(c.radius_mm),
                "height_mm": num(c.height_mm),
                "feed_mm_min": num(c.feed_mm_min),
                "samples": c.samples,
                "g_um": num(c.g_um()),
                "h_um": num(c.h_um),
                "ccw": zone(&c.ccw),
                "cw": zone(&c.cw),
                "bidirectional": zone(&c.both),
            })
        })
        .collect();
    let g = d.circle_zones.iter().map(|c| c.g_um()).fold(0.0, f64::max);
    let h = d.circle_zones.iter().map(|c| c.h_um).fold(0.0, f64::max);
    v["plane"] = json!(plane_name(d.plane));
    v["pitch_mm"] = json!({"x": d.pitch_mm[0], "y": d.pitch_mm[1], "z": d.pitch_mm[2]});
    v["circles"] = Value::Array(circles);
    v["minimum_zone"] = json!({"g_um": num(g), "h_um": num(h)});
    v["filter_upr"] = num(d.filter_upr);
    v["circular_deviation_g_filtered_um"] = num(d
        .filtered_g_um
        .iter()
        .flatten()
        .flatten()
        .copied()
        .fold(f64::NAN, f64::max));
}

/// ISO 230-4 radial deviation F of every circle, [ccw, cw], as (F max, F min) in µm: the
/// largest and smallest deviation of the actual path from the nominal circle, with the centre
/// of the least-squares circle of all samples (ISO 230-4's second way to set the centre) and the
/// radius as the calibrated bar measures it: D − |p − t| = the plotted deviation + the length
/// offset e (so F carries the instrument's length error, which its calibration bounds). None:
/// the circle was not run in that direction.
pub fn radial_deviation_f(d: &Diagnosis) -> Vec<[Option<(f64, f64)>; 2]> {
    let finite = |x: f64| if x.is_finite() { x } else { 0.0 };
    let e = finite(d.lsq_setup_um[3]);
    // The plotted deviation is about the fitted set-up t_f: D − |p − t_f| − e_f. About the
    // least-squares t_l it is that + u·(t_l − t_f) − (e_l − e_f) (µm offsets on a radius of
    // mm: exact to 10⁻⁶ µm), u = p/|p| the sample's direction from the table ball.
    let fitted = d.fitted_setup_um();
    let (a, b) = d.plane;
    let n = 3 - a - b;
    let shift: Vec<f64> = (0..4)
        .map(|k| finite(d.lsq_setup_um[k]) - fitted[k])
        .collect();
    let mut out = vec![[None, None]; d.circles.len()];
    for run in &d.runs {
        let Some(slot) = out.get_mut(run.circle) else {
            continue;
        };
        let cell = &mut slot[usize::from(!run.ccw)];
        let (r, h) = d
            .circles
            .get(run.circle)
            .map_or((1.0, 0.0), |c| (c.radius_mm, c.height_mm));
        let len = r.hypot(h);
        for i in run.range.clone() {
            let (sin, cos) = d.angle_rad[i].sin_cos();
            let u_dot_shift = (r * (cos * shift[a] + sin * shift[b]) + h * shift[n]) / len;
            let v = d.measured_dev_um[i] + u_dot_shift - shift[3] + e;
            if !v.is_finite() {
                continue;
            }
            *cell = Some(match *cell {
                Some((max, min)) => (f64::max(max, v), f64::min(min, v)),
                None => (v, v),
            });
        }
    }
    out
}

/// The verdict against a tolerance on G (µm): pass if every circle's G (each direction,
/// minimum-zone centre) is at most `tol_um`, and the line `jdbb diagnose --tolerance-um` prints.
pub fn tolerance_verdict(diag: &Diagnosis, tol_um: f64) -> (bool, String) {
    let g = diag
        .circle_zones
        .iter()
        .map(|c| c.g_um())
        .fold(f64::NAN, f64::max);
    let pass =
        !diag.circle_zones.is_empty() && diag.circle_zones.iter().all(|c| c.g_um() <= tol_um);
    let line = format!(
        "{}: largest circular deviation G {} µm (minimum zone, per circle and direction) {} tolerance {} µm",
        if pass { "PASS" } else { "FAIL" },
        crate::units::format_to(g, diag.final_rms_um),
        if pass { "<=" } else { ">" },
        tol_um
    );
    (pass, line)
}

/// The line under a named following error: the radius it takes off each circle at each feed the
/// test ran (`Diagnosis::radius_loss`), and the loop gain of a loop without feed-forward that
/// loses as much (`model::following_error_kv_per_s`).
fn radius_loss_text(d: &Diagnosis, q_ms2: f64) -> String {
    let losses: Vec<String> = d
        .radius_loss
        .iter()
        .map(|l| {
            format!(
                "{} µm at R {:.3} mm, {:.0} mm/min",
                format_estimate(l.loss_um, l.sigma_um),
                l.radius_mm,
                l.feed_mm_min
            )
        })
        .collect();
    let kv = match crate::model::following_error_kv_per_s(q_ms2) {
        Some(kv) => format!("as a loop without feed-forward: Kv {kv:.1} 1/s"),
        None => "not positive: circles drawn larger, feed-forward above 100 %".into(),
    };
    if losses.is_empty() {
        return kv;
    }
    format!("radius loss q·v²/R: {}; {kv}", losses.join(", "))
}
