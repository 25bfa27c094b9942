//! What a diagnosis is: its options, the effects found and not significant, and the facts about them.
use super::*;

/// The reporting floor (µm): an effect that changes D by less than this everywhere on the test is
/// not named. A fifth of a typical J-DBB sample's noise (0.2 µm), half of the 0.1 µm resolution
/// commercial ballbars quote, and far below the machine errors a ballbar test is for (µm).
pub const MIN_EFFECT_UM: f64 = 0.05;

/// Knobs of the diagnosis.
#[derive(Debug, Clone)]
pub struct Options {
    /// The forward selection's limits and BIC penalty.
    pub select: SelectOptions,
    /// Number of angle harmonics reported for the residual.
    pub harmonics: usize,
    /// Account for correlated noise (the residual's integrated autocorrelation time, see
    /// [`Diagnosis::noise_tau_int`]); off, every sample counts as independent, as before.
    pub correlated_noise: bool,
    /// The controller whose settings [`Diagnosis::g_if_compensated_um`] assumes entered (a
    /// reversal spike is compensable where it compensates it); None: the settings every
    /// control has ([`crate::model::settable::is_setting`]).
    pub controller: Option<crate::model::settable::Controller>,
}

/// Most groups the selection names by default: a real machine carries eight effects at once
/// (issue 27), a worn screw's ends are a group of their own beside its gap, and the selection
/// stops by its criterion long before on a machine with fewer (the cap of 8 left a dense
/// machine's scale mismatch and reversal spike unnamed, `tests/tests/real_machine.rs`).
pub const MAX_GROUPS: usize = 12;

impl Default for Options {
    fn default() -> Self {
        Options {
            select: SelectOptions {
                gamma: 0.5,
                min_peak: MIN_EFFECT_UM,
                max_effects: MAX_GROUPS,
                ..SelectOptions::default()
            },
            harmonics: 8,
            correlated_noise: true,
            controller: None,
        }
    }
}

/// One reported effect: its fitted parameters (exact geometry) and the selection step that added it.
#[derive(Debug, Clone)]
pub struct Found {
    pub effect: Effect,
    pub params: Vec<f64>,
    pub param_sigma: Vec<Option<f64>>,
    pub value: f64,
    pub sigma: Option<f64>,
    /// RMS (µm) of the residual after this step of the selection.
    pub rms_after_um: f64,
    /// RMS before / RMS after this step.
    pub rms_ratio: f64,
    /// Change of BIC by this step (negative = better).
    pub delta_bic: f64,
    /// RMS (µm) of the radial deviation this effect alone makes along the path, after the same
    /// set-up removal as the plotted curve; NaN for the set-up itself.
    pub contribution_rms_um: f64,
    /// This effect's share of the error: contribution_rms_um² over the sum of every machine
    /// effect's contribution_rms_um² and the residual's mean square (final_rms_um²), so the
    /// shares and [`Diagnosis::residual_share`] add up to 1; NaN for the set-up.
    pub share: f64,
    /// The test's G (µm) with the radial deviation this effect alone makes taken out of the
    /// measured traces: what G would be without it, which its share of G is read from
    /// ([`crate::report`], *Shares*); NaN for the set-up.
    pub g_without_um: f64,
}

/// An effect the selection chose but whose value its σ does not tell from zero.
#[derive(Debug, Clone, PartialEq)]
pub struct NotSignificant {
    /// Effect name, as in [`Found`].
    pub name: String,
    /// Unit of `value`.
    pub unit: &'static str,
    /// Its value in the exact refit.
    pub value: f64,
    /// Its standard uncertainty, timing included.
    pub sigma_value: f64,
    /// Its parameters in the exact refit, by name (a spike's decay shows why its height is
    /// undetermined: τ far below the sample period).
    pub params: Vec<(&'static str, f64)>,
    /// The standard error of each of `params` (None: not determined).
    pub params_sigma: Vec<Option<f64>>,
    /// Why it is not named, in words.
    pub reason: String,
}

impl NotSignificant {
    /// `f` as not named, for `reason`.
    pub(super) fn of(f: &Found, reason: String) -> NotSignificant {
        NotSignificant {
            name: f.effect.name(),
            unit: f.effect.unit(),
            value: f.value,
            sigma_value: f.sigma.unwrap_or(f64::NAN),
            params: f
                .effect
                .param_names()
                .iter()
                .copied()
                .zip(f.params.iter().copied())
                .collect(),
            params_sigma: f.param_sigma.clone(),
            reason,
        }
    }
}

/// The result of [`diagnose`].
#[derive(Debug, Clone)]
pub struct Diagnosis {
    pub samples: usize,
    pub baseline_rms_um: f64,
    pub baseline_pv_um: f64,
    /// Set-up (setup_offset, length_offset) then machine effects, in the order selected.
    pub effects: Vec<Found>,
    /// Groups of names (effects, or effect components like `setup_offset.z`) the test cannot
    /// tell apart.
    pub confounded: Vec<Vec<String>>,
    pub final_rms_um: f64,
    /// The residual's share of the error (what no named effect explains: noise and the rest):
    /// final_rms_um² over the same sum as [`Found::share`].
    pub residual_share: f64,
    /// baseline RMS / final RMS.
    pub gain: f64,
    /// Amplitude (µm) of residual harmonics 1..=n against the angle in the main plane.
    pub harmonics_um: Vec<f64>,
    /// Candidates that were tried (names).
    pub candidates: Vec<String>,
    /// Effects that would have lowered the BIC but reach less than the floor
    /// ([`SelectOptions::min_peak`], µm) anywhere on D: name and that bound (µm).
    pub below_floor: Vec<(String, f64)>,
    /// The floor applied (µm).
    pub floor_um: f64,
    /// Effects the selection chose whose final value is within 2σ of zero, once σ counts the
    /// uncertainty of the timing (a reversal spike's height against the synchronisation's
    /// timing σ); not named, and the rest refitted without them.
    pub not_significant: Vec<NotSignificant>,
    /// Per sample: angle (rad) in the main plane; measured deviation with the fitted set-up
    /// removed, D − (|p − t| + e) with t, e the fitted `setup_offset` and `length_offset` (µm:
    /// the one centre every output uses); and the extended model's deviation after the same
    /// removal, i.e. its machine effects (µm).
    pub angle_rad: Vec<f64>,
    pub measured_dev_um: Vec<f64>,
    pub model_dev_um: Vec<f64>,
    /// The least-squares centre and length of all samples (a detail: the centre ISO 230-4's F is
    /// taken about), D ≈ |p − t| + e, as [t_x, t_y, t_z, e] in µm, t being where the table ball is
    /// relative to where it was assumed (the one sign of a set-up offset in every command) and
    /// e the bar's length offset (a component the path cannot determine is held at 0).
    pub lsq_setup_um: [f64; 4],
    /// Main plane (axis indices) of the angle.
    pub plane: (usize, usize),
    /// The distinct circles (nominal radius and height) of the path.
    pub circles: Vec<Circle>,
    /// The samples cut into runs of one circle in one direction without gaps (see [`split_runs`]).
    pub runs: Vec<Run>,
    /// The test's circular deviation G (µm): the largest of the circles' G, each the radial width
    /// of the minimum zone (ISO 230-4, minimum-zone centre) of one circle in one direction
    /// ([`Diagnosis::circle_zones`]). The one G every output shows.
    pub circular_deviation_g_um: f64,
    /// What-if: the test's G (µm, as `circular_deviation_g_um`) with the deviation of every
    /// named effect a controller setting removes taken out of the measured traces — backlash,
    /// scale, squareness, cyclic error ([`crate::model::settable::is_setting`] with
    /// [`Options::controller`]) at least [`crate::model::settable::SIGNIFICANT_SIGMAS`] σ from zero,
    /// as `jdbb compensate` acts on them: the G the machine would have with those settings
    /// entered. Equal to the measured G where no such effect is named.
    pub g_if_compensated_um: f64,
    /// The test's hysteresis H (µm): the largest of the circles' H.
    pub hysteresis_h_um: f64,
    /// Without a pitch for any moving axis: the pitch the residual suggests trying
    /// (`--pitch`), where it is above its noise and one pitch stands out ([`crate::diagnose::pitch_hint`]).
    pub pitch_hint: Option<crate::diagnose::pitch_hint::PitchHint>,
    /// Per circle: conditions (radius, height, feed) and ISO 230-4 G and H with the
    /// minimum-zone centre ([`crate::diagnose::zone`]).
    pub circle_zones: Vec<CircleZone>,
    /// Per circle, [ccw, cw]: G (µm, minimum zone) of the traces low-passed at
    /// [`Diagnosis::filter_upr`] undulations per revolution ([`crate::diagnose::zone::filtered_g_um`]);
    /// None where the circle was not run that way.
    pub filtered_g_um: Vec<[Option<f64>; 2]>,
    /// The cut-off of that low-pass, undulations per revolution.
    pub filter_upr: f64,
    /// The pitch per axis the diagnosis was given (mm), which the periodic effects refer to.
    pub pitch_mm: [Option<f64>; 3],
    /// The arc each circle's samples cover (in `circles`' order): 360° on a full circle. On a
    /// partial arc `harmonics_um` is empty, and see `weak_on_arc`.
    pub arcs: Vec<ArcCover>,
    /// On a partial arc: the candidates whose shape differs from the set-up's and the scale's by
    /// less than [`PARTIAL_ARC_MIN_FREE`] of itself, each with what it resembles. They are
    /// tried — the part that differs can carry them where the data are good — but where one of
    /// the group is named, the others are its alternative on this arc.
    pub weak_on_arc: Vec<WeakOnArc>,
    /// How many samples the residual's noise makes one independent sample: its integrated
    /// autocorrelation time τ_int (`numerics::correlation`), 1 for white noise. Above
    /// [`CORRELATED_TAU`] the selection counted m/τ_int samples and every σ is √τ_int larger
    /// than a white-noise fit's.
    pub noise_tau_int: f64,
    /// Where `following_error` is named: the radius it takes off each circle at each speed the
    /// test ran it (a feed sweep runs one radius at several), q·v²/R ([`RadiusLoss`]).
    pub radius_loss: Vec<RadiusLoss>,
    /// Per axis that reverses and per end: the peak a person sees in the trace after the
    /// reversals there, with its duration ([`crate::diagnose::reversal`]).
    pub reversal_peaks: Vec<crate::diagnose::reversal::ReversalPeak>,
}

/// The radius a named following error takes off one circle at one feed: q·v²/R
/// ([`crate::model::radius_loss_um`]), with v the mean commanded speed of the circle's runs at
/// that feed.
#[derive(Debug, Clone, PartialEq)]
pub struct RadiusLoss {
    pub radius_mm: f64,
    /// The speed the circle ran at (mm/min, the synchronised feed, override included).
    pub feed_mm_min: f64,
    pub loss_um: f64,
    pub sigma_um: Option<f64>,
}

/// [`Diagnosis::radius_loss`]: for each circle and each speed its runs ran at (speeds within
/// 2 % are one), q·v²/R from the named following error in `found`; empty where none is named.
pub(super) fn radius_losses(
    path: &Path,
    found: &[Found],
    runs: &[Run],
    circles: &[Circle],
) -> Vec<RadiusLoss> {
    let Some(f) = found.iter().find(|f| f.effect == Effect::FollowingError) else {
        return vec![];
    };
    let mut out: Vec<RadiusLoss> = vec![];
    for run in runs {
        let n = run.range.len();
        if n == 0 {
            continue;
        }
        let speed_mm_s = path.v_mm_s[run.range.clone()]
            .iter()
            .map(|v| (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt())
            .sum::<f64>()
            / n as f64;
        let feed_mm_min = 60.0 * speed_mm_s;
        let radius_mm = circles[run.circle].radius_mm;
        let known = out.iter().any(|l| {
            l.radius_mm == radius_mm && (l.feed_mm_min - feed_mm_min).abs() <= 0.02 * feed_mm_min
        });
        if known || !(feed_mm_min > 0.0 && radius_mm > 0.0) {
            continue;
        }
        let per_q = crate::model::radius_loss_um(1.0, feed_mm_min, radius_mm);
        out.push(RadiusLoss {
            radius_mm,
            feed_mm_min,
            loss_um: f.value * per_q,
            sigma_um: f.sigma.map(|s| s * per_q),
        });
    }
    out
}

/// A candidate a partial arc barely tells from others (see [`Diagnosis::weak_on_arc`]).
#[derive(Debug, Clone, PartialEq)]
pub struct WeakOnArc {
    /// The candidate first, then the set-up components and scales its shape resembles.
    pub names: Vec<String>,
    /// The fraction of its column's norm² that the others do not explain (0..1; 1 on a shape of
    /// its own).
    pub free_fraction: f64,
}

/// An effect of the exact refit, with the statistics of the selection step it came from (the
/// later of two for a backlash whose ends differ).
pub(super) struct Chosen {
    pub(super) effect: Effect,
    pub(super) start: Vec<f64>,
    pub(super) held_lag: bool,
    pub(super) rms_after: f64,
    pub(super) rms_ratio: f64,
    pub(super) delta_bic: f64,
}

/// A machine effect alone with its refitted parameters, from one pass over the samples: the
/// most it moves D (µm), and its residual D − |p| (µm) as rᵀr and Jᵀr against the set-up's free
/// columns (−u, 1), which its share needs.
pub(super) struct Alone {
    pub(super) peak_um: f64,
    pub(super) rr: f64,
    pub(super) jtr: nalgebra::DVector<f64>,
}

impl Alone {
    pub(super) fn of(path: &Path, f: &Found, setup_free: &[usize]) -> Alone {
        let d = EffectSet::new(vec![f.effect]).distances_mm(path, &f.params);
        let mut jtr = nalgebra::DVector::<f64>::zeros(setup_free.len());
        let (mut rr, mut peak_um) = (0.0, 0.0f64);
        for (p, d) in path.p_mm.iter().zip(&d) {
            let r = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
            let res = 1e3 * (d - r);
            rr += res * res;
            peak_um = peak_um.max(res.abs());
            let column = [-p[0] / r, -p[1] / r, -p[2] / r, 1.0];
            for (a, &c) in setup_free.iter().enumerate() {
                jtr[a] += column[c] * res;
            }
        }
        Alone { peak_um, rr, jtr }
    }
}

/// The axis of a backlash (uniform or by ends).
pub(super) fn backlash_axis(e: Effect) -> Option<Axis> {
    match e {
        Effect::Backlash(a) | Effect::BacklashEnds(a) => Some(a),
        _ => None,
    }
}

/// The named `interference_k` that are the named `cyclic_k` read where axis k is when it lags
/// its command (a named servo mismatch gives each axis of its pair a delay τ_k), as (index of
/// the interference, index of the cyclic error, why) in `found`. A cyclic error is a function of
/// the screw's position; an axis τ late is at p − v·τ, so its cyclic error A_s·sin ωp +
/// A_c·cos ωp (ω = 2π/pitch) is read as itself plus v·ωτ·(A_c·sin ωp − A_s·cos ωp) to first
/// order: an interference (A_s, A_c per mm/s) of exactly (ωτ·A_c, −ωτ·A_s). One the data
/// cannot tell from that (each part within 3σ, the σ of both sides) is the cyclic error's, not
/// a speed-dependent error of the scale.
pub(super) fn lag_explained(found: &[Found], path: &Path) -> Vec<(usize, usize, String)> {
    let mut out = vec![];
    for (ii, f) in found.iter().enumerate() {
        let Effect::Interference(axis) = f.effect else {
            continue;
        };
        let k = axis.index();
        let Some(pitch) = path.pitch_mm[k] else {
            continue;
        };
        let Some(ci) = found.iter().position(|c| c.effect == Effect::Cyclic(axis)) else {
            continue;
        };
        // The axis's delay (s) and its σ from a named servo mismatch of a pair with it.
        let Some((tau_s, tau_sigma_s)) = found.iter().find_map(|g| {
            let Effect::ServoMismatch(pair) = g.effect else {
                return None;
            };
            let (a, b) = pair.axes();
            let half = if a == axis {
                0.5
            } else if b == axis {
                -0.5
            } else {
                return None;
            };
            let (dtau, lag) = (g.params[0], g.params[1]);
            let (sd, sl) = (g.param_sigma[0]?, g.param_sigma[1]?);
            Some((1e-3 * (lag + half * dtau), 1e-3 * sl.hypot(0.5 * sd)))
        }) else {
            continue;
        };
        let c = &found[ci];
        let (Some(sa_s), Some(sa_c)) = (c.param_sigma[0], c.param_sigma[1]) else {
            continue;
        };
        let (Some(si_s), Some(si_c)) = (f.param_sigma[0], f.param_sigma[1]) else {
            continue;
        };
        let omega = 2.0 * std::f64::consts::PI / pitch;
        let (a_s, a_c) = (c.params[0], c.params[1]);
        let predicted = [omega * tau_s * a_c, -omega * tau_s * a_s];
        let predicted_sigma = [
            omega * (tau_s * sa_c).hypot(a_c * tau_sigma_s),
            omega * (tau_s * sa_s).hypot(a_s * tau_sigma_s),
        ];
        let fitted = [f.params[0], f.params[1]];
        let fitted_sigma = [si_s, si_c];
        let agrees = (0..2).all(|p| {
            (fitted[p] - predicted[p]).abs() <= 3.0 * fitted_sigma[p].hypot(predicted_sigma[p])
        });
        if agrees {
            let letter = axis.letter().to_ascii_uppercase();
            out.push((
                ii,
                ci,
                format!(
                    "it is cyclic_{} read where {letter} is while it lags its command by {:.2} ms (servo): a delay τ reads a cyclic error A at p − v·τ, a speed-dependent part 2π·τ/pitch·A, here ({:.5}, {:.5}) µm/(mm/s) for ({:.5}, {:.5}) fitted; kept in the model as part of the cyclic error, not an error of its own",
                    axis.letter(),
                    1e3 * tau_s,
                    predicted[0],
                    predicted[1],
                    fitted[0],
                    fitted[1]
                ),
            ));
        }
    }
    out.sort_by_key(|e| e.0);
    out
}

/// Why the data cannot carry a refitted effect, if they cannot: parameters the data do not
/// determine (no finite σ), a reversal spike whose decay time is shorter than one sample
/// period `period_s` (it would be gone before the next sample), or one whose decay time the
/// data fix to no better than half of itself ([`POORLY_DETERMINED`]).
///
/// The rule for what is named: every parameter that gives an effect's size — its value, and a
/// spike's decay time, which sets how much of the spike the samples see — determined to better
/// than half of itself, σ counting the timing. Its value is checked by the 2σ rule where the
/// refit's σ includes the timing; the decay time here. A spike whose τ is that uncertain has a
/// height that trades against τ along the fit's valley (20.4 ± 5.6 µm for a true 7.9 at 250 Hz,
/// issue 20): its height is a point on that valley, not a measurement.
pub(super) fn cannot_carry(f: &Found, period_s: f64) -> Option<String> {
    if !f.value.is_finite()
        || f.sigma.is_none_or(|s| !s.is_finite())
        || f.param_sigma
            .iter()
            .any(|s| s.is_none_or(|s| !s.is_finite()))
    {
        return Some("its parameters are not determined by the data".into());
    }
    if let Effect::ReversalSpike(_) = f.effect {
        let tau_ms = f.params[1];
        if tau_ms.is_nan() || tau_ms * 1e-3 < period_s {
            return Some(format!(
                "its decay time is shorter than one sample period ({:.3} ms): the data cannot show it",
                period_s * 1e3
            ));
        }
        let tau_sigma = f.param_sigma[1].unwrap_or(f64::INFINITY);
        if tau_sigma >= POORLY_DETERMINED * tau_ms.abs() {
            return Some(format!(
                "its decay time {tau_ms:.1} ± {tau_sigma:.1} ms is not determined to better than half of itself: its height trades against it"
            ));
        }
    }
    None
}
