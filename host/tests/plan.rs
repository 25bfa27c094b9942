//! `jdbb plan`: the program a ballbar test runs.
//!
//! Every dialect's program is parsed back by an independent parser (the `gcode` crate) and run
//! through a small interpreter written here from the controllers' documentation — not from the
//! writer — and its motion (end points, arc centres and senses, arc sweeps, feeds, dwells) must
//! equal plan.json's segments. Coordinates are compared to 1e-4 mm: the crate reads numbers as
//! f32 (7 digits; 2e-5 mm at a few hundred mm).
use std::path::Path;

use gcode::{Code, Value};
use jdbb::plan::{
    calibration_circles, default_calibration_distances, instrument, line_d_range, plan,
    write_program, Close, Dialect, LineRole, Plan, PlanSpec, Plane, Purpose, Segment, Sense,
    ON_CIRCLE_NM, ON_CIRCLE_SEARCH_DEG,
};
use jdbb_core::calib::Calibration;
mod common;
use common::jdbb;

const TOL_MM: f64 = 1e-4;

// ---------------------------------------------------------------------------------------------
// The test-side interpreter.

/// One motion or pause of a parsed program.
#[derive(Debug, Clone, PartialEq)]
enum Motion {
    Rapid {
        to: [f64; 3],
    },
    Line {
        from: [f64; 3],
        to: [f64; 3],
        feed: f64,
    },
    /// `plane`: `xy`, `zx` or `yz` by G17/G18/G19; `sweep_deg` from the geometry: + for G3.
    Arc {
        from: [f64; 3],
        to: [f64; 3],
        centre: [f64; 3],
        g3: bool,
        plane: &'static str,
        sweep_deg: f64,
        feed: f64,
    },
    Dwell(f64),
    Stop,
}

/// What the interpreter makes of a program.
struct Run {
    motions: Vec<Motion>,
    end: String,
}

/// The arc plane of G17, G18, G19 as RS274/NGC defines it (LinuxCNC "G17-G19.1", grbl and
/// Marlin's `plan_arc` use the same axis order): the first and second axis of the plane — the
/// arc's angle is measured from the first towards the second, and G2 is clockwise seen from the
/// positive end of the remaining axis — and the offset letters of the two.
fn plane_of(g: u32) -> (&'static str, usize, usize, [char; 2]) {
    match g {
        17 => ("xy", 0, 1, ['I', 'J']),
        18 => ("zx", 2, 0, ['K', 'I']),
        19 => ("yz", 1, 2, ['J', 'K']),
        _ => unreachable!(),
    }
}

fn literal(v: &Value) -> f64 {
    match v {
        Value::Literal(x) => *x as f64,
        other => panic!("{other:?} in a generated program: only literal numbers"),
    }
}

/// Interpret `src` as `dialect` reads it: modal G0/G1/G2/G3 with absolute X/Y/Z (G90, G21),
/// I/J/K as incremental centre offsets, F modal in mm/min (G94), G17/G18/G19, G4 with the
/// dialect's units, M0 a stop, the dialect's program end. Anything else is an error: the
/// writer must not emit what this reader does not know.
fn interpret(src: &str, dialect: Dialect) -> Run {
    let program = gcode::parse(src).unwrap_or_else(|d| panic!("{dialect:?}: parse errors {d:?}"));
    let mut pos = [f64::NAN; 3];
    let mut plane = 17;
    let mut feed: Option<f64> = None;
    // Marlin has no G94: F in mm/min is its only feed mode.
    let (mut absolute, mut metric, mut per_minute) = (false, false, dialect == Dialect::Marlin);
    let mut motions = vec![];
    let mut end = None;
    for block in &program.blocks {
        assert!(
            block.word_addresses.is_empty(),
            "{dialect:?}: bare words {:?}",
            block.word_addresses
        );
        for code in &block.codes {
            assert!(end.is_none(), "{dialect:?}: a block after the program end");
            match code {
                Code::General(g) => {
                    let args: Vec<(char, f64)> = g
                        .args
                        .iter()
                        .map(|a| (a.letter, literal(&a.value)))
                        .collect();
                    let arg = |c: char| args.iter().find(|(l, _)| *l == c).map(|(_, v)| *v);
                    match (g.number.major(), g.number.minor().map(|m| m.get())) {
                        (m @ 0..=3, None) => {
                            assert!(
                                absolute && metric && per_minute,
                                "{dialect:?}: modes not set before motion"
                            );
                            let mut to = pos;
                            for (k, c) in ['X', 'Y', 'Z'].iter().enumerate() {
                                if let Some(v) = arg(*c) {
                                    to[k] = v;
                                }
                            }
                            if let Some(f) = arg('F') {
                                feed = Some(f);
                            }
                            assert!(
                                to.iter().all(|v| v.is_finite()),
                                "{dialect:?}: position unknown"
                            );
                            match m {
                                0 => motions.push(Motion::Rapid { to }),
                                1 => motions.push(Motion::Line {
                                    from: pos,
                                    to,
                                    feed: feed.expect("G1 without a feed"),
                                }),
                                _ => {
                                    let (name, a, b, letters) = plane_of(plane);
                                    let normal = 3 - a - b;
                                    let normal_letter = ['I', 'J', 'K'][normal];
                                    assert!(
                                        arg(normal_letter).is_none(),
                                        "{dialect:?}: {normal_letter} in the {name} plane"
                                    );
                                    let mut centre = pos;
                                    for l in letters {
                                        let axis = (l as usize) - ('I' as usize);
                                        centre[axis] += arg(l).unwrap_or(0.0);
                                    }
                                    let ang =
                                        |p: &[f64; 3]| (p[b] - centre[b]).atan2(p[a] - centre[a]);
                                    let (a0, a1) = (ang(&pos), ang(&to));
                                    let sweep = if m == 3 {
                                        let s = (a1 - a0).rem_euclid(std::f64::consts::TAU);
                                        if s < 1e-9 {
                                            std::f64::consts::TAU
                                        } else {
                                            s
                                        }
                                    } else {
                                        let s = (a0 - a1).rem_euclid(std::f64::consts::TAU);
                                        -(if s < 1e-9 { std::f64::consts::TAU } else { s })
                                    };
                                    motions.push(Motion::Arc {
                                        from: pos,
                                        to,
                                        centre,
                                        g3: m == 3,
                                        plane: name,
                                        sweep_deg: sweep.to_degrees(),
                                        feed: feed.expect("arc without a feed"),
                                    });
                                }
                            }
                            pos = to;
                        }
                        (4, None) => {
                            // LinuxCNC: "G4 P- seconds"; grbl: P seconds (mc_dwell(float seconds));
                            // Marlin: P milliseconds or S seconds; Fanuc: X seconds with a decimal
                            // point, or P in milliseconds.
                            let s = match dialect {
                                Dialect::Linuxcnc | Dialect::Grbl => arg('P').expect("G4 P"),
                                Dialect::Marlin => arg('P')
                                    .map(|ms| ms / 1000.0)
                                    .or(arg('S'))
                                    .expect("G4 P or S"),
                                Dialect::Fanuc => arg('X')
                                    .or(arg('P').map(|ms| ms / 1000.0))
                                    .expect("G4 X or P"),
                            };
                            motions.push(Motion::Dwell(s));
                        }
                        (p @ 17..=19, None) => plane = p,
                        (21, None) => metric = true,
                        (90, None) => absolute = true,
                        (94, None) => per_minute = true,
                        (40, None) => {}
                        (91, Some(1)) => assert!(
                            matches!(dialect, Dialect::Linuxcnc | Dialect::Grbl),
                            "{dialect:?} has no G91.1"
                        ),
                        (64, None) => {
                            assert_eq!(dialect, Dialect::Linuxcnc);
                            assert!(arg('P').is_some_and(|p| p <= 0.001 + 1e-9), "G64 tolerance");
                        }
                        other => panic!("{dialect:?}: unexpected G{other:?}"),
                    }
                }
                Code::Miscellaneous(m) => match m.number.major() {
                    0 => motions.push(Motion::Stop),
                    n @ (2 | 30 | 400) => end = Some(format!("M{n}")),
                    n => panic!("{dialect:?}: unexpected M{n}"),
                },
                other => panic!("{dialect:?}: unexpected {other:?}"),
            }
        }
    }
    Run {
        motions,
        end: end.expect("no program end"),
    }
}

/// `%` delimiters and O numbers of a program, as the crate's core parser reports them (the AST
/// drops them).
#[derive(Default)]
struct Outline {
    delimiters: usize,
    program_numbers: Vec<u32>,
}

impl gcode::core::Diagnostics for Outline {}

struct OutlineBlock<'a>(&'a mut Outline);

impl gcode::core::Diagnostics for OutlineBlock<'_> {}

impl gcode::core::ProgramVisitor for Outline {
    fn start_block(&mut self) -> gcode::core::ControlFlow<impl gcode::core::BlockVisitor + '_> {
        gcode::core::ControlFlow::Continue(OutlineBlock(self))
    }
}

impl gcode::core::BlockVisitor for OutlineBlock<'_> {
    fn program_number(&mut self, number: u32, _span: gcode::core::Span) {
        self.0.program_numbers.push(number);
    }
    fn program_delimiter(&mut self, _span: gcode::core::Span) {
        self.0.delimiters += 1;
    }
}

fn outline(src: &str) -> Outline {
    let mut o = Outline::default();
    gcode::core::parse(src, &mut o);
    o
}

// ---------------------------------------------------------------------------------------------
// Comparison with the plan.

fn close(a: &[f64; 3], b: &[f64; 3], tol: f64) -> bool {
    (0..3).all(|k| (a[k] - b[k]).abs() <= tol)
}

fn d(c: &[f64; 3], p: &[f64; 3]) -> f64 {
    ((p[0] - c[0]).powi(2) + (p[1] - c[1]).powi(2) + (p[2] - c[2]).powi(2)).sqrt()
}

/// The program's motion equals the plan's segments, one to one, and keeps D in range.
fn check_program(plan: &Plan, src: &str, dialect: Dialect) {
    let run = interpret(src, dialect);
    let want_end = match dialect {
        Dialect::Linuxcnc | Dialect::Grbl => "M2",
        Dialect::Fanuc => "M30",
        Dialect::Marlin => "M400",
    };
    assert_eq!(run.end, want_end, "{dialect:?}");
    let o = outline(src);
    match dialect {
        Dialect::Fanuc => {
            assert_eq!(o.delimiters, 2, "Fanuc: % at the start and the end");
            assert_eq!(o.program_numbers, vec![1000]);
            assert!(src.starts_with("%\nO1000"), "Fanuc: % then O1000 first");
            // Fanuc reads a number without a decimal point in least input increments.
            for line in src
                .lines()
                .filter(|l| !l.starts_with('(') && !l.starts_with('O'))
            {
                for word in line.split_whitespace().filter(|w| w.len() > 1) {
                    let (letter, num) = word.split_at(1);
                    if "XYZIJKF".contains(letter) {
                        assert!(num.contains('.'), "Fanuc: `{word}` without a decimal point");
                    }
                }
            }
        }
        _ => assert_eq!(o.delimiters, 0, "{dialect:?}: no % (grbl rejects it)"),
    }
    if dialect == Dialect::Marlin {
        assert!(
            src.lines().all(|l| !l.contains('(')),
            "Marlin: ; comments only"
        );
    }
    assert_eq!(
        run.motions.len(),
        plan.segments.len(),
        "{dialect:?}: one program block per segment"
    );
    let c = &plan.centre_mm;
    let inst = &plan.instrument;
    let mut mounted = false;
    for (k, (m, s)) in run.motions.iter().zip(&plan.segments).enumerate() {
        let at = format!("{dialect:?} segment {k}: {m:?} vs {s:?}");
        match (m, s) {
            (Motion::Rapid { to }, Segment::Rapid { to_mm, .. }) => {
                assert!(close(to, to_mm, TOL_MM), "{at}");
            }
            (Motion::Stop, Segment::Stop) => mounted = true,
            (Motion::Dwell(t), Segment::Dwell { seconds }) => {
                assert!((t - seconds).abs() < 1e-6, "{at}");
            }
            (
                Motion::Line { from, to, feed },
                Segment::Line {
                    from_mm,
                    to_mm,
                    feed_mm_min,
                    ..
                },
            ) => {
                assert!(
                    close(from, from_mm, TOL_MM) && close(to, to_mm, TOL_MM),
                    "{at}"
                );
                assert!((feed - feed_mm_min).abs() < 1e-3, "{at}");
            }
            (
                Motion::Arc {
                    from,
                    to,
                    centre,
                    g3,
                    plane,
                    sweep_deg,
                    feed,
                },
                Segment::Arc {
                    centre_mm,
                    radius_mm,
                    plane: p,
                    sense,
                    sweep_deg: sw,
                    feed_mm_min,
                    from_mm,
                    to_mm,
                    ..
                },
            ) => {
                assert!(
                    close(from, from_mm, TOL_MM) && close(to, to_mm, TOL_MM),
                    "{at}"
                );
                assert!(close(centre, centre_mm, TOL_MM), "{at}");
                assert_eq!(*plane, p.name(), "{at}");
                assert_eq!(*g3, *sense == Sense::Ccw, "{at}: G3 is ccw");
                // Arc ends off the circle's axes are rounded to the 1 µm grid: at most 0.71 µm
                // along the circle at each end.
                let tol_deg = (2.0 * 0.71e-3 / radius_mm).to_degrees() + 1e-5;
                assert!((sweep_deg - sw).abs() < tol_deg, "{at}: sweep");
                assert!(
                    sweep_deg.abs() <= 180.0 + tol_deg,
                    "{at}: arcs at most 180°"
                );
                assert!((feed - feed_mm_min).abs() < 1e-3, "{at}");
                // Start and end on the circle: controllers refuse a radius mismatch (grbl
                // beyond 0.005 mm); the grid rounds ends to at most 0.71 µm.
                let (r0, r1) = (d(centre, from), d(centre, to));
                assert!(
                    (r0 - radius_mm).abs() < 1e-3 && (r1 - radius_mm).abs() < 1e-3,
                    "{at}"
                );
            }
            _ => panic!("{at}: different kinds"),
        }
        // D along the interpreted motion once the instrument is mounted.
        if mounted {
            for t in 0..=200 {
                let t = t as f64 / 200.0;
                let p = match m {
                    Motion::Line { from, to, .. } => {
                        std::array::from_fn(|q| from[q] + t * (to[q] - from[q]))
                    }
                    Motion::Arc {
                        from,
                        centre,
                        plane,
                        sweep_deg,
                        ..
                    } => {
                        let (a, b) = match *plane {
                            "xy" => (0, 1),
                            "zx" => (2, 0),
                            _ => (1, 2),
                        };
                        let r = d(centre, from);
                        let a0 = (from[b] - centre[b]).atan2(from[a] - centre[a]);
                        let ang = a0 + t * sweep_deg.to_radians();
                        let mut p = *centre;
                        p[a] += r * ang.cos();
                        p[b] += r * ang.sin();
                        p
                    }
                    _ => break,
                };
                let dd = d(c, &p);
                assert!(
                    dd >= inst.d_min_mm - 1e-3 && dd <= inst.d_max_mm + 1e-3,
                    "{at}: D {dd} outside {}..{}",
                    inst.d_min_mm,
                    inst.d_max_mm
                );
            }
        }
    }
}

fn spec(radii: &[f64], heights: &[f64], plane: Plane, dialect: Dialect) -> PlanSpec {
    PlanSpec::machine_test(radii, heights, plane, 1000.0, [100.0, 50.0, -20.0], dialect)
}

// ---------------------------------------------------------------------------------------------
// Library tests.

#[test]
fn every_dialect_parses_back_to_the_plan() {
    let cal = Calibration::DEFAULT;
    for dialect in Dialect::ALL {
        for plane in [Plane::Xy, Plane::Yz, Plane::Zx] {
            // Two radii at two heights, an odd start angle and lead-in (arc ends off the axes,
            // pieces under 180°), and the default tuning.
            let mut odd = spec(&[90.0, 85.5], &[-10.0, 12.5], plane, dialect);
            odd.start_deg = 37.0;
            odd.lead_in_deg = 45.0;
            odd.overshoot_deg = 200.0;
            odd.dwell_s = 0.25;
            odd.reversal_dwell_s = 2.5;
            // The vertical-plane test's partial arc: 220° from −20°, ends off the axes.
            let partial = spec(&[90.0, 85.0], &[0.0, 10.0], plane, dialect).with_arc(220.0);
            let mut partial = PlanSpec {
                start_deg: -20.0,
                ..partial
            };
            partial.reversal_dwell_s = 0.5;
            for s in [spec(&[90.0, 85.0], &[0.0], plane, dialect), odd, partial] {
                let p = plan(&s, &cal).unwrap();
                assert_eq!(p.program, dialect.program_name());
                let back = Plan::from_json(Path::new("plan.json"), &p.to_json()).unwrap();
                check_program(&back, &write_program(&back, dialect), dialect);
            }
        }
    }
}

/// A test that closes on itself in time (`--close`): the first circle again at the end, or the
/// circles in ABBA order, in plan.json (`close`, and its circles in execution order) and in every
/// dialect's program; `jdbb plan --close abba` writes it.
#[test]
fn a_test_closes_on_itself_in_every_dialect() {
    let cal = Calibration::DEFAULT;
    for dialect in Dialect::ALL {
        for (close, radii) in [
            (Close::None, vec![90.0, 85.0]),
            (Close::First, vec![90.0, 85.0, 90.0]),
            (Close::Abba, vec![90.0, 85.0, 85.0, 90.0]),
        ] {
            let s = PlanSpec {
                close,
                ..spec(&[90.0, 85.0], &[0.0], Plane::Xy, dialect)
            };
            let p = plan(&s, &cal).unwrap();
            let back = Plan::from_json(Path::new("plan.json"), &p.to_json()).unwrap();
            assert_eq!(back.close, close);
            let got: Vec<f64> = back.circles.iter().map(|c| c.radius_mm).collect();
            assert_eq!(got, radii, "{close:?}");
            check_program(&back, &write_program(&back, dialect), dialect);
        }
    }
    // A plan that does not close is written as before `close` existed (its id, which records
    // made for it carry, unchanged), and reads as not closed.
    let p = plan(&spec(&[90.0], &[0.0], Plane::Xy, Dialect::Linuxcnc), &cal).unwrap();
    let old = p.to_json();
    assert!(!old.contains("close"), "{old}");
    assert_eq!(
        Plan::from_json(Path::new("plan.json"), &old).unwrap().close,
        Close::None
    );
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("abba");
    let o = jdbb(&[
        "plan",
        "--radius",
        "90",
        "--radius",
        "85",
        "--close",
        "abba",
        "--feed",
        "1000",
        "--centre",
        "100,50,-20",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let p = Plan::read(&out.join("plan.json")).unwrap();
    assert_eq!(p.close, Close::Abba);
    assert_eq!(p.circles.len(), 4);
}

#[test]
fn calibration_test_parses_back_and_covers_the_range() {
    let cal = Calibration::DEFAULT;
    let inst = instrument(&cal).unwrap();
    let distances = default_calibration_distances(&inst, 2.0);
    assert_eq!(distances.len(), 4);
    let mut s = spec(&[], &[], Plane::Xy, Dialect::Linuxcnc);
    s.purpose = Purpose::CalibrationTest;
    s.circles = calibration_circles(&distances);
    for dialect in Dialect::ALL {
        s.dialect = dialect;
        let p = plan(&s, &cal).unwrap();
        assert_eq!(p.purpose, Purpose::CalibrationTest);
        check_program(&p, &write_program(&p, dialect), dialect);
    }
    let p = plan(&s, &cal).unwrap();
    // Three latitudes per sphere, each circle on its sphere.
    assert_eq!(p.circles.len(), 12);
    for (k, c) in p.circles.iter().enumerate() {
        assert!((c.d_mm - distances[k / 3]).abs() < 2e-3, "{c:?}");
        assert!(c.height_mm >= 0.0);
    }
    // Deflections from near straight to near the frames' limit: the spheres span the range.
    let phi: Vec<f64> = distances
        .iter()
        .map(|&d| inst.deflection_deg(d).unwrap())
        .collect();
    assert!(phi[0] > 65.0 && phi[0] < 75.0, "{phi:?}");
    assert!(phi[3] < 15.0, "{phi:?}");
    // On the lowest sphere the straight chord between the feed-in starts at latitudes 0° and
    // 30° would dip below D_min, so that move is a spiral of several lines, each in range.
    let starts: Vec<[f64; 3]> = p
        .segments
        .iter()
        .filter_map(|s| match s {
            Segment::Line {
                role: LineRole::FeedIn,
                from_mm,
                ..
            } => Some(*from_mm),
            _ => None,
        })
        .collect();
    let (lo, _) = line_d_range(&p.centre_mm, &starts[0], &starts[1]);
    assert!(
        lo < inst.d_min_mm,
        "the chord stays at {lo}: this test would not test the spiral"
    );
    let moves_to_1 = p
        .segments
        .iter()
        .filter(|s| {
            matches!(
                s,
                Segment::Line {
                    role: LineRole::Move,
                    circle: 1,
                    ..
                }
            )
        })
        .count();
    assert!(moves_to_1 >= 2, "{moves_to_1} line(s)");
}

#[test]
fn plan_structure_and_range_hold() {
    let cal = Calibration::DEFAULT;
    let p = plan(
        &spec(
            &[90.0, 85.0, 95.0],
            &[0.0, 20.0],
            Plane::Zx,
            Dialect::Linuxcnc,
        ),
        &cal,
    )
    .unwrap();
    assert!(
        matches!(p.segments[0], Segment::Rapid { .. }),
        "first a rapid"
    );
    assert_eq!(p.segments[1], Segment::Stop, "then the stop");
    assert_eq!(p.start_mm, p.segments[0].to_mm().unwrap());
    // Segments chain, arcs ≤ 180°, and D stays in range at every millimetre of every segment.
    let mut at = p.start_mm;
    let inst = &p.instrument;
    for (k, s) in p.segments.iter().enumerate() {
        if let Some(from) = s.from_mm() {
            assert_eq!(
                from,
                at,
                "segment {k} starts where {} ended",
                k.saturating_sub(1)
            );
            at = s.to_mm().unwrap();
            assert!(close(&p.position_at(k, 0.0), &from, 1e-6));
            assert!(close(&p.position_at(k, 1e9), &at, 1e-6), "{s:?}");
        }
        if let Segment::Arc { sweep_deg, .. } = s {
            assert!(sweep_deg.abs() <= 180.0 + 1e-9 && *sweep_deg != 0.0);
        }
        if k >= 2 {
            let len = p.length_mm(k);
            let n = (len.ceil() as usize).max(1);
            for m in 0..=n {
                let dd = d(&p.centre_mm, &p.position_at(k, len * m as f64 / n as f64));
                assert!(inst.contains(dd), "segment {k} at {m}/{n}: D {dd}");
            }
        }
    }
    // Per height, per radius: the circles come in that order.
    let rh: Vec<(f64, f64)> = p
        .circles
        .iter()
        .map(|c| (c.radius_mm, c.height_mm))
        .collect();
    assert_eq!(
        rh,
        [
            (90.0, 0.0),
            (85.0, 0.0),
            (95.0, 0.0),
            (90.0, 20.0),
            (85.0, 20.0),
            (95.0, 20.0)
        ]
    );
}

#[test]
fn zx_ccw_turns_z_towards_x() {
    // Plane zx: i = z, j = x. A ccw arc from θ0 = 0 (on +z) first moves towards +x: a rotation
    // about +y, which is G3 in G18 (checked against the G-code in the parse-back test).
    let p = plan(
        &spec(&[90.0], &[0.0], Plane::Zx, Dialect::Linuxcnc),
        &Calibration::DEFAULT,
    )
    .unwrap();
    let k = p
        .segments
        .iter()
        .position(|s| {
            matches!(
                s,
                Segment::Arc {
                    sense: Sense::Ccw,
                    ..
                }
            )
        })
        .unwrap();
    let a = p.position_at(k, 0.0);
    let b = p.position_at(k, 1.0);
    assert!(
        (a[2] - (-20.0 + 90.0)).abs() < 1e-9 && (a[0] - 100.0).abs() < 1e-9,
        "{a:?}"
    );
    assert!(b[0] > a[0] + 0.9 && b[2] < a[2], "{a:?} -> {b:?}");
    assert!(write_program(&p, Dialect::Linuxcnc).contains("G18"));
}

#[test]
fn position_and_duration_known_answers() {
    let p = plan(
        &spec(&[90.0], &[0.0], Plane::Xy, Dialect::Linuxcnc),
        &Calibration::DEFAULT,
    )
    .unwrap();
    // Segment 6 is the first lead-in arc (5: the corner dwell after the feed-in): ccw from (190, 50) about (100, 50); a quarter of it
    // (πR/2 along the path) is at 90°, (100, 140).
    assert_eq!(p.segments[5], Segment::Dwell { seconds: 0.1 });
    assert!(matches!(
        p.segments[6],
        Segment::Arc {
            sense: Sense::Ccw,
            ..
        }
    ));
    let q = p.position_at(6, std::f64::consts::FRAC_PI_2 * 90.0);
    assert!(close(&q, &[100.0, 140.0, -20.0], 1e-9), "{q:?}");
    assert!((p.length_mm(6) - std::f64::consts::PI * 90.0).abs() < 1e-9);
    // After the stop, the take-up: 0.5 mm along the feed-in's direction to the feed-in start.
    assert_eq!(p.length_mm(2), 0.5);
    assert_eq!(p.position_at(2, 0.0), p.start_mm);
    // A dwell is where the previous motion ended; the feed-in is 2 mm long.
    assert_eq!(p.segments[3], Segment::Dwell { seconds: 1.0 });
    assert_eq!(p.position_at(3, 0.0), p.position_at(2, 0.5));
    assert!((p.length_mm(4) - 2.0).abs() < 1e-12);
    // Time: 4 half circles of πR each way, the take-up of 0.5 mm, feed-in and feed-out of 2 mm,
    // at 1000 mm/min; three 1 s dwells (after the take-up, at the reversal, after the feed-out)
    // and two corner dwells of 0.1 s (after the feed-in, before the feed-out).
    let want = (8.0 * std::f64::consts::PI * 90.0 + 4.5) / 1000.0 * 60.0 + 3.0 + 0.2;
    assert!(
        (p.nominal_duration_s() - want).abs() < 1e-9,
        "{} vs {want}",
        p.nominal_duration_s()
    );
}

#[test]
fn out_of_range_is_refused_naming_the_range() {
    let cal = Calibration::DEFAULT;
    for (r, h) in [(70.0, 0.0), (100.0, 0.0), (90.0, 60.0), (81.0, 0.0)] {
        let e = plan(&spec(&[r], &[h], Plane::Xy, Dialect::Linuxcnc), &cal).unwrap_err();
        let m = e.to_string();
        assert_eq!(e.exit_code(), 2, "{m}");
        assert!(m.contains("79.836..99.500 mm") && m.contains("±75°"), "{m}");
    }
    // 81 mm: the circle fits but its feed-in and take-up start (78.5 mm) do not.
    let m = plan(&spec(&[81.0], &[0.0], Plane::Xy, Dialect::Linuxcnc), &cal)
        .unwrap_err()
        .to_string();
    assert!(
        m.contains("feed-in, with the take-up before it, starts 2.5 mm inside, at D = 78.500 mm"),
        "{m}"
    );
    // Another instrument, another range.
    let long = Calibration {
        l1_mm: 60.0,
        l2_mm: 60.0,
        ..Calibration::DEFAULT
    };
    assert!(plan(&spec(&[110.0], &[0.0], Plane::Xy, Dialect::Linuxcnc), &long).is_ok());
    assert!(plan(&spec(&[110.0], &[0.0], Plane::Xy, Dialect::Linuxcnc), &cal).is_err());
}

#[test]
fn instrument_range_from_the_core_geometry() {
    // Law of cosines at the frames' 75°: D² = L1² + L2² + 2·L1·L2·cos 75°; then 0.5 mm inside,
    // rounded inwards to the micrometre.
    let inst = instrument(&Calibration::DEFAULT).unwrap();
    let d75 = (5000.0 * (1.0 + 75f64.to_radians().cos())).sqrt();
    assert!((d75 - 79.3353).abs() < 1e-4, "{d75}");
    assert_eq!(inst.d_min_mm, ((d75 + 0.5) * 1000.0).ceil() / 1000.0);
    assert_eq!(inst.d_min_mm, 79.836);
    assert_eq!(inst.d_max_mm, 99.5);
    // φ at the range's ends: just inside the frames' 75°, and near straight bars.
    let phi_min_d = inst.deflection_deg(inst.d_min_mm).unwrap();
    assert!(phi_min_d < 75.0 && phi_min_d > 72.0, "{phi_min_d}");
}

#[test]
fn dwell_words_per_dialect() {
    // 0.25 s: seconds for LinuxCNC and grbl (G4 P), Fanuc (G4 X with a decimal point),
    // milliseconds for Marlin (G4 P).
    let mut s = spec(&[90.0], &[0.0], Plane::Xy, Dialect::Linuxcnc);
    s.dwell_s = 0.25;
    let p = plan(&s, &Calibration::DEFAULT).unwrap();
    for (dialect, word) in [
        (Dialect::Linuxcnc, "G4 P0.25\n"),
        (Dialect::Grbl, "G4 P0.25\n"),
        (Dialect::Fanuc, "G4 X0.25\n"),
        (Dialect::Marlin, "G4 P250\n"),
    ] {
        let text = write_program(&p, dialect);
        assert!(text.contains(word), "{dialect:?}: {text}");
    }
}

#[test]
fn plan_json_round_trips_and_bad_files_name_the_place() {
    let p = plan(
        &spec(&[90.0], &[5.0], Plane::Yz, Dialect::Grbl),
        &Calibration::DEFAULT,
    )
    .unwrap();
    let text = p.to_json();
    let back = Plan::from_json(Path::new("p.json"), &text).unwrap();
    assert_eq!(back, p);
    assert_eq!(back.to_json(), text);
    let v: serde_json::Value = serde_json::from_str(&text).unwrap();
    assert_eq!(v["format"], "jdbb-plan");
    assert_eq!(v["version"], 2);
    assert_eq!(v["arc"]["sweep_deg"], 360.0);
    assert_eq!(v["arc"]["data_sweep_deg"], 360.0);
    assert_eq!(v["purpose"], "machine-test");
    assert_eq!(v["segments"][0]["kind"], "rapid");
    assert_eq!(v["segments"][1]["kind"], "stop");
    assert_eq!(v["segments"][2]["role"], "move");
    assert_eq!(v["segments"][4]["role"], "feed_in");
    assert_eq!(v["segments"][5]["kind"], "dwell");
    assert_eq!(v["segments"][6]["sense"], "ccw");
    assert_eq!(v["segments"][6]["role"], "lead_in");
    // Malformed JSON: file:line:col.
    let e = Plan::from_json(
        Path::new("p.json"),
        "{\n  \"format\": \"jdbb-plan\",\n  oops\n}",
    )
    .unwrap_err();
    assert!(e.to_string().starts_with("p.json:3:"), "{e}");
    assert_eq!(e.exit_code(), 2);
    // Another version or format.
    let e = Plan::from_json(
        Path::new("p.json"),
        &text.replace("\"version\": 2", "\"version\": 7"),
    )
    .unwrap_err();
    assert!(e.to_string().contains("version 7"), "{e}");
    let e = Plan::from_json(Path::new("p.json"), "{\"format\": \"other\"}").unwrap_err();
    assert!(e.to_string().contains("not a plan"), "{e}");
    // A program that is not a file name beside plan.json.
    let e = Plan::from_json(
        Path::new("p.json"),
        &text.replace("\"ballbar.nc\"", "\"../x.nc\""),
    )
    .unwrap_err();
    assert!(e.to_string().contains("not a file name"), "{e}");
    // Segments that do not chain.
    let mut broken = p.clone();
    if let Segment::Line { from_mm, .. } = &mut broken.segments[4] {
        from_mm[0] += 1.0;
    }
    let e = Plan::from_json(Path::new("p.json"), &broken.to_json()).unwrap_err();
    assert!(e.to_string().contains("does not start where"), "{e}");
}

// ---------------------------------------------------------------------------------------------
// The command.

#[test]
fn command_writes_the_plan_and_program_of_every_dialect() {
    let dir = tempfile::tempdir().unwrap();
    for dialect in Dialect::ALL {
        let out = dir.path().join(dialect.name());
        let o = jdbb(&[
            "plan",
            "--radius",
            "90",
            "--radius",
            "85",
            "--height",
            "0",
            "--feed",
            "1000",
            "--centre",
            "-100,50,-20",
            "--dialect",
            dialect.name(),
            "--out",
            out.to_str().unwrap(),
        ]);
        let stdout = String::from_utf8_lossy(&o.stdout);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        assert!(
            stdout.contains("table ball centre:   X -100.000  Y 50.000  Z -20.000 mm"),
            "{stdout}"
        );
        assert!(
            stdout.contains("start point:         X -12.500  Y 50.000  Z -20.000 mm"),
            "{stdout}"
        );
        assert!(stdout.contains("79.836..99.500 mm"), "{stdout}");
        let p = Plan::read(&out.join("plan.json")).unwrap();
        assert_eq!(p.dialect, dialect);
        let program = std::fs::read_to_string(out.join(&p.program)).unwrap();
        check_program(&p, &program, dialect);
    }
}

#[test]
fn command_refuses_what_cannot_be_meant() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("p");
    let out = out.to_str().unwrap();
    let fails = |args: &[&str], want: &str| {
        let o = jdbb(args);
        let err = String::from_utf8_lossy(&o.stderr).to_string();
        assert_eq!(o.status.code(), Some(2), "{args:?}: {err}");
        assert!(err.contains(want), "{args:?}: wanted `{want}` in {err}");
        assert!(!err.contains("panicked"));
    };
    let base = ["plan", "--feed", "1000", "--out", out];
    let with = |extra: &[&'static str]| -> Vec<&str> {
        base.iter().copied().chain(extra.iter().copied()).collect()
    };
    fails(
        &with(&["--radius", "60", "--centre", "0,0,0"]),
        "range 79.836..99.500 mm",
    );
    fails(
        &with(&["--radius", "90", "--height", "80", "--centre", "0,0,0"]),
        "range 79.836..99.500 mm",
    );
    fails(
        &with(&["--radius", "90", "--centre", "0,0"]),
        "three numbers X,Y,Z",
    );
    fails(&with(&["--radius", "90", "--centre", "0,x,0"]), "Y is");
    fails(
        &with(&[
            "--radius",
            "90",
            "--centre",
            "0,0,0",
            "--dialect",
            "heidenhain",
        ]),
        "linuxcnc, grbl, fanuc, marlin",
    );
    fails(
        &with(&["--radius", "90", "--centre", "0,0,0", "--plane", "xz"]),
        "xy, yz or zx",
    );
    fails(
        &with(&[
            "--radius",
            "90",
            "--centre",
            "0,0,0",
            "--lead-in-deg",
            "400",
        ]),
        "0 to 360",
    );
    fails(
        &with(&["--radius", "90", "--centre", "0,0,0", "--dwell-s", "nan"]),
        "not a finite number",
    );
    fails(&with(&["--centre", "0,0,0"]), "--radius");
    for bad in ["0", "-20", "360.5", "inf"] {
        let want = if bad == "inf" {
            "not a finite number"
        } else {
            "the arc each circle runs is above 0° and at most 360°"
        };
        fails(
            &with(&["--radius", "90", "--centre", "0,0,0", "--arc-deg", bad]),
            want,
        );
    }
    fails(
        &with(&["--radius", "90", "--centre", "0,0,0", "--arc-deg", "40"]),
        "leave no data arc",
    );
    fails(
        &with(&[
            "--calibration-test",
            "--centre",
            "0,0,0",
            "--arc-deg",
            "220",
        ]),
        "cannot be used with",
    );
    fails(
        &with(&[
            "--radius",
            "90",
            "--centre",
            "0,0,0",
            "--arc-deg",
            "220",
            "--lead-in-deg",
            "200",
        ]),
        "leave no data arc",
    );
    assert!(!Path::new(out).exists(), "nothing written on refusal");
    // An existing plan is kept unless --force.
    let ok = with(&["--radius", "90", "--centre", "0,0,0"]);
    assert!(jdbb(&ok).status.success());
    fails(&ok, "add --force");
    let mut forced = ok.clone();
    forced.push("--force");
    assert!(jdbb(&forced).status.success());
}

#[test]
fn command_reads_a_calibration_and_plans_the_calibration_test() {
    let dir = tempfile::tempdir().unwrap();
    let cal = dir.path().join("cal.toml");
    std::fs::write(
        &cal,
        "l1_mm = 60.0\nl2_mm = 60.0\n[enc1]\ncounts_per_rev = 20000\nzero_count = 0\ndirection = \"Positive\"\n[enc2]\ncounts_per_rev = 20000\nzero_count = 0\ndirection = \"Negative\"\n",
    )
    .unwrap();
    let out = dir.path().join("c");
    let o = jdbb(&[
        "plan",
        "--calibration-test",
        "--feed",
        "2000",
        "--centre",
        "0,0,0",
        "--calibration",
        cal.to_str().unwrap(),
        "--dialect",
        "marlin",
        "--out",
        out.to_str().unwrap(),
    ]);
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    // 60 mm bars: D up to 119.5 mm.
    assert!(
        stdout.contains("..119.500 mm (L1 60 mm, L2 60 mm"),
        "{stdout}"
    );
    let p = Plan::read(&out.join("plan.json")).unwrap();
    assert_eq!(p.purpose, Purpose::CalibrationTest);
    assert_eq!(p.instrument.l1_mm, 60.0);
    let program = std::fs::read_to_string(out.join("ballbar.gcode")).unwrap();
    check_program(&p, &program, Dialect::Marlin);
    // A broken calibration file: file:line:col, exit 2.
    std::fs::write(&cal, "l1_mm = 60.0\nl2_mm = \"long\"\n").unwrap();
    let o = jdbb(&[
        "plan",
        "--radius",
        "90",
        "--feed",
        "1000",
        "--centre",
        "0,0,0",
        "--calibration",
        cal.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--force",
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(err.contains("cal.toml:2:"), "{err}");
}

// ---------------------------------------------------------------------------------------------
// Partial arcs (issue 15 §4).

/// The angle (degrees) of `p` about circle `c`'s centre in `plane`, from its first axis.
fn angle_deg(plane: Plane, centre: &[f64; 3], p: &[f64; 3]) -> f64 {
    let (i, j, _) = plane.axes();
    (p[j] - centre[j]).atan2(p[i] - centre[i]).to_degrees()
}

#[test]
fn a_partial_arc_stays_on_its_arc_and_runs_it_both_ways() {
    // The vertical-plane test: 220° from −20° in zx, lead-in and overshoot 20° from inside it,
    // so the data arc is 0° to 180°, ccw then cw.
    let mut s = spec(&[90.0, 85.0], &[0.0], Plane::Zx, Dialect::Linuxcnc).with_arc(220.0);
    s.start_deg = -20.0;
    let p = plan(&s, &Calibration::DEFAULT).unwrap();
    assert_eq!(
        (
            p.arc.start_deg,
            p.arc.sweep_deg,
            p.arc.lead_in_deg,
            p.arc.overshoot_deg,
            p.arc.data_start_deg,
            p.arc.data_sweep_deg
        ),
        (-20.0, 220.0, 20.0, 20.0, 0.0, 180.0)
    );
    for (k, circle) in p.circles.iter().enumerate() {
        // The arcs of circle k between its feed-in and feed-out, in order.
        let arcs: Vec<(Sense, String, f64, f64)> = p
            .segments
            .iter()
            .filter_map(|sg| match sg {
                Segment::Arc {
                    circle,
                    sense,
                    role,
                    start_deg,
                    sweep_deg,
                    ..
                } if *circle == k => Some((
                    *sense,
                    serde_json::to_value(role)
                        .unwrap()
                        .as_str()
                        .unwrap()
                        .to_string(),
                    *start_deg,
                    *sweep_deg,
                )),
                _ => None,
            })
            .collect();
        let want = [
            (Sense::Ccw, "lead_in", 340.0, 20.0),
            (Sense::Ccw, "data", 0.0, 180.0),
            (Sense::Ccw, "overshoot", 180.0, 20.0),
            (Sense::Cw, "lead_in", 200.0, -20.0),
            (Sense::Cw, "data", 180.0, -180.0),
            (Sense::Cw, "overshoot", 0.0, -20.0),
        ];
        assert_eq!(arcs.len(), want.len(), "{arcs:?}");
        for (got, want) in arcs.iter().zip(want) {
            assert_eq!((got.0, got.1.as_str()), (want.0, want.1), "{arcs:?}");
            // An arc end off the axes moves along its circle to a grid point on it (at most
            // ON_CIRCLE_SEARCH_DEG); the data arc's ends at 0° and 180° are grid points.
            let (tol, wrap) = (ON_CIRCLE_SEARCH_DEG + 1e-9, |x: f64| {
                (x + 180.0).rem_euclid(360.0) - 180.0
            });
            assert!(
                wrap(got.2 - want.2).abs() < tol && (got.3 - want.3).abs() < 2.0 * tol,
                "{arcs:?}"
            );
            if want.1 == "data" {
                assert!((got.3 - want.3).abs() < 1e-9, "{arcs:?}");
            }
        }
        // Every point of every arc of the circle is on [−20°, 200°]; the arc ends are on the
        // 1 µm grid and on the circle within ON_CIRCLE_NM (ends near −20° and 200° are off the
        // axes: rounded where the angle says they were up to 0.71 µm off it, and a controller
        // drew a spiral).
        for (n, sg) in p.segments.iter().enumerate() {
            let Segment::Arc {
                circle: ci,
                from_mm,
                to_mm,
                ..
            } = sg
            else {
                continue;
            };
            if *ci != k {
                continue;
            }
            let len = p.length_mm(n);
            for m in 0..=200 {
                let q = p.position_at(n, len * m as f64 / 200.0);
                let mut a = angle_deg(Plane::Zx, &circle.centre_mm, &q);
                if a < -90.0 {
                    a += 360.0;
                }
                assert!(
                    (-20.0 - 1e-6..=200.0 + 1e-6).contains(&a),
                    "segment {n}: {a}° is off the arc"
                );
            }
            for end in [from_mm, to_mm] {
                for x in end {
                    assert!(
                        ((x * 1000.0) - (x * 1000.0).round()).abs() < 1e-6,
                        "{end:?}"
                    );
                }
                let r = d(&circle.centre_mm, end);
                assert!(
                    (r - circle.radius_mm).abs() <= ON_CIRCLE_NM * 1e-6,
                    "{end:?}: r {r}"
                );
            }
        }
    }
    // The ends of the arc are off the axes: the feed-in at −20°, the reversal at 200°.
    let a = match &p.segments[6] {
        Segment::Arc { from_mm, .. } => angle_deg(Plane::Zx, &p.circles[0].centre_mm, from_mm),
        other => panic!("{other:?}"),
    };
    assert!((a + 20.0).abs() <= ON_CIRCLE_SEARCH_DEG, "{a}");
    // Time: 2 × 220° per circle at 1000 mm/min (less what the ends moved inwards onto grid
    // points on the circles), take-up, feed-ins and feed-outs, dwells.
    let arcs_mm: f64 = p
        .segments
        .iter()
        .filter(|sg| matches!(sg, Segment::Arc { .. }))
        .map(Segment::length_mm)
        .sum();
    let nominal_mm: f64 = [90.0, 85.0]
        .iter()
        .map(|r| 2.0 * 220f64.to_radians() * r)
        .sum();
    assert!(
        arcs_mm <= nominal_mm + 1e-9
            && arcs_mm >= nominal_mm - 4.0 * ON_CIRCLE_SEARCH_DEG.to_radians() * 90.0 * 2.0,
        "{arcs_mm} mm of arcs for {nominal_mm}"
    );
    let lines_mm: f64 = p
        .segments
        .iter()
        .filter(|sg| matches!(sg, Segment::Line { .. }))
        .map(Segment::length_mm)
        .sum();
    let dwells: f64 = p
        .segments
        .iter()
        .filter_map(|sg| match sg {
            Segment::Dwell { seconds } => Some(*seconds),
            _ => None,
        })
        .sum();
    let want = (arcs_mm + lines_mm) / 1000.0 * 60.0 + dwells;
    assert!((p.nominal_duration_s() - want).abs() < 1e-6);
    // In yz from −20° the arc stays above −R·sin 20° below the table ball's centre.
    let mut s = spec(&[90.0], &[0.0], Plane::Yz, Dialect::Linuxcnc).with_arc(220.0);
    s.start_deg = -20.0;
    let p = plan(&s, &Calibration::DEFAULT).unwrap();
    let (lo, hi) = p.travel_mm();
    let below = p.centre_mm[2] - lo[2];
    assert!(
        (below - 90.0 * 20f64.to_radians().sin()).abs() < 2e-3,
        "{below}"
    );
    assert!((hi[2] - p.centre_mm[2] - 90.0).abs() < 1e-3);
    assert!((hi[1] - lo[1] - 180.0).abs() < 1e-3);
}

#[test]
fn lead_in_and_overshoot_of_a_partial_arc_come_from_inside_it() {
    // 150° from 30° with no lead-in and a 10° overshoot: data 30° to 170°, the machine within
    // 30°..180°; without lead-in and overshoot the data arc is the whole arc.
    let mut s = spec(&[90.0], &[0.0], Plane::Xy, Dialect::Grbl);
    s.arc_deg = 150.0;
    s.start_deg = 30.0;
    s.lead_in_deg = 0.0;
    s.overshoot_deg = 10.0;
    let p = plan(&s, &Calibration::DEFAULT).unwrap();
    assert_eq!((p.arc.data_start_deg, p.arc.data_sweep_deg), (30.0, 140.0));
    let data: Vec<(f64, f64)> = p
        .segments
        .iter()
        .filter_map(|sg| match sg {
            Segment::Arc {
                role: jdbb::plan::ArcRole::Data,
                start_deg,
                sweep_deg,
                ..
            } => Some((*start_deg, *sweep_deg)),
            _ => None,
        })
        .collect();
    // The ends at 30° and 170° move along the circle to grid points on it.
    let want = [(30.0, 140.0), (170.0, -140.0)];
    assert_eq!(data.len(), 2);
    for (got, want) in data.iter().zip(want) {
        assert!(
            (got.0 - want.0).abs() <= ON_CIRCLE_SEARCH_DEG
                && (got.1 - want.1).abs() <= 2.0 * ON_CIRCLE_SEARCH_DEG,
            "{data:?}"
        );
    }
    check_program(&p, &write_program(&p, Dialect::Grbl), Dialect::Grbl);
    s.overshoot_deg = 0.0;
    let p = plan(&s, &Calibration::DEFAULT).unwrap();
    assert_eq!((p.arc.data_start_deg, p.arc.data_sweep_deg), (30.0, 150.0));
    assert!(p.segments.iter().all(|sg| !matches!(
        sg,
        Segment::Arc {
            role: jdbb::plan::ArcRole::LeadIn | jdbb::plan::ArcRole::Overshoot,
            ..
        }
    )));
}

#[test]
fn version_1_plans_still_read_as_full_circles() {
    // A plan written before partial arcs: version 1, no `arc`. Its arc is the full circle its
    // segments run (here from 37° with a 45° lead-in and a 200° overshoot).
    let mut s = spec(&[90.0], &[0.0], Plane::Xy, Dialect::Linuxcnc);
    s.start_deg = 37.0;
    s.lead_in_deg = 45.0;
    s.overshoot_deg = 200.0;
    let p = plan(&s, &Calibration::DEFAULT).unwrap();
    let mut v: serde_json::Value = serde_json::from_str(&p.to_json()).unwrap();
    v.as_object_mut().unwrap().remove("arc");
    v["version"] = 1.into();
    let old = Plan::from_json(Path::new("old.json"), &v.to_string()).unwrap();
    assert_eq!(old.version, 1);
    // Its arc read from the segments, whose ends are grid points on the circle (within
    // ON_CIRCLE_SEARCH_DEG of the angles asked for).
    let (a, b) = (old.arc, p.arc);
    for (x, y) in [
        (a.start_deg, b.start_deg),
        (a.lead_in_deg, b.lead_in_deg),
        (a.overshoot_deg, b.overshoot_deg),
        (a.data_start_deg, b.data_start_deg),
    ] {
        assert!(
            (x - y).abs() <= 2.0 * ON_CIRCLE_SEARCH_DEG,
            "{a:?} vs {b:?}"
        );
    }
    assert_eq!(
        (a.sweep_deg, a.data_sweep_deg),
        (b.sweep_deg, b.data_sweep_deg)
    );
    assert_eq!(old.segments, p.segments);
    assert!(!old.arc.is_partial());
    // A version-2 plan without its arc, or with an arc that is none, is refused.
    let mut v: serde_json::Value = serde_json::from_str(&p.to_json()).unwrap();
    v["arc"]["sweep_deg"] = 400.0.into();
    let e = Plan::from_json(Path::new("p.json"), &v.to_string()).unwrap_err();
    assert!(e.to_string().contains("`arc`"), "{e}");
    v.as_object_mut().unwrap().remove("arc");
    let e = Plan::from_json(Path::new("p.json"), &v.to_string()).unwrap_err();
    assert!(e.to_string().contains("arc"), "{e}");
}

#[test]
fn command_plans_the_vertical_plane_test() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("yz");
    let o = jdbb(&[
        "plan",
        "--radius",
        "90",
        "--plane",
        "yz",
        "--arc-deg",
        "220",
        "--start-deg",
        "-20",
        "--feed",
        "1000",
        "--centre",
        "100,50,-20",
        "--dialect",
        "fanuc",
        "--out",
        out.to_str().unwrap(),
    ]);
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(
        stdout.contains("arc:                 220° from -20° to 200° of the plane's first axis (y), not beyond: lead-in 20°, data 0° to 180°, overshoot 20°, each way"),
        "{stdout}"
    );
    assert!(
        stdout.contains("note: the arc passes 30.780 mm below the table ball's centre"),
        "{stdout}"
    );
    assert!(!stdout.contains("must reach it"), "{stdout}");
    let p = Plan::read(&out.join("plan.json")).unwrap();
    assert!(p.arc.is_partial());
    let program = std::fs::read_to_string(out.join(&p.program)).unwrap();
    check_program(&p, &program, Dialect::Fanuc);
    // At 2000 mm/min the 2 mm feed-in is too short to reach the feed, which the synchronisation
    // of a partial arc needs: (33.3 mm/s)² / 300 mm/s² / 0.8 = 4.63 mm.
    let o = jdbb(&[
        "plan",
        "--radius",
        "90",
        "--plane",
        "yz",
        "--arc-deg",
        "220",
        "--start-deg",
        "-20",
        "--feed",
        "2000",
        "--centre",
        "100,50,-20",
        "--out",
        dir.path().join("fast").to_str().unwrap(),
    ]);
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success());
    assert!(
        stdout.contains("needs a feed-in of 4.7 mm or more (--feed-in-mm), this one is 2.0 mm"),
        "{stdout}"
    );
}

#[test]
fn every_dialect_parses_a_volumetric_plan_back() {
    // Cones at three heights on two distances, and the zx and yz 220° arcs: planes change
    // within the program (G17, G18, G19), and each block still equals its segment.
    use jdbb::volumetric::plan::{plan as volumetric, VolumetricSpec};
    for dialect in Dialect::ALL {
        let spec = VolumetricSpec {
            distances_mm: vec![90.0, 85.0],
            heights_mm: vec![],
            base: spec(&[90.0], &[0.0], Plane::Xy, dialect),
        };
        let p = volumetric(&spec, &Calibration::DEFAULT).unwrap();
        let back = Plan::from_json(Path::new("plan.json"), &p.to_json()).unwrap();
        assert_eq!(back, p);
        let src = write_program(&back, dialect);
        for g in ["G18", "G19"] {
            assert!(src.lines().any(|l| l == g), "{dialect:?}: no {g} line");
        }
        check_program(&back, &src, dialect);
    }
}
