use super::*;

/// A record of `n` samples at 1 kHz, D 90 mm with a slow wave, header on line 1.
fn record_text(n: usize) -> Vec<String> {
    (0..n)
        .map(|i| {
            format!(
                "{i},{},0,0,{:.7}",
                1000 * i,
                90.0 + 0.001 * (i as f64 * 0.01).sin()
            )
        })
        .collect()
}

fn write_record(dir: &FsPath, lines: &[String]) -> PathBuf {
    let f = dir.join("rec.csv");
    std::fs::write(
        &f,
        format!("seq,t_us,enc1,enc2,d_mm\n{}\n", lines.join("\n")),
    )
    .unwrap();
    f
}

#[test]
fn glitches_are_set_aside_with_their_lines_and_marked_samples_counted() {
    let dir = tempfile::tempdir().unwrap();
    let mut lines = record_text(1000);
    lines[500] = "500,500000,0,0,50.0".into();
    lines[700] = "# suspect: 700,700000,0,0,NaN: D is not finite".into();
    let rec = Record::read(&write_record(dir.path(), &lines)).unwrap();
    assert_eq!(rec.t_s.len(), 998);
    assert_eq!(rec.marked, 1);
    assert_eq!(
        rec.glitches,
        [Glitch {
            line: 502,
            t_s: 0.5,
            d_mm: 50.0
        }]
    );
    assert!(!rec.holds_line(502) && rec.holds_line(503) && !rec.holds_line(702));
    assert!(rec.d_mm.iter().all(|&d| (d - 90.0).abs() < 0.01));
    let note = rec.set_aside_note(None).unwrap();
    assert!(
        note.contains("set aside 1 glitch sample") && note.contains("line 502 at 0.500 s"),
        "{note}"
    );
    assert!(note.contains("1 sample the recorder marked"), "{note}");
    // Glitches everywhere are no glitches but a broken instrument: refused.
    for k in (0..1000).step_by(50) {
        lines[k + 3] = format!("{},{},0,0,50.0", k + 3, 1000 * (k + 3));
    }
    let e = Record::read(&write_record(dir.path(), &lines))
        .unwrap_err()
        .to_string();
    assert!(e.contains("faulty instrument or cable"), "{e}");
}

#[test]
fn a_record_longer_than_the_bound_is_refused_where_it_passes_it() {
    // Issue 28 (8): memory is bounded by the samples a record is read with.
    let dir = tempfile::tempdir().unwrap();
    let f = write_record(dir.path(), &record_text(50));
    assert_eq!(Record::read_at_most(&f, 50).unwrap().t_s.len(), 50);
    let e = Record::read_at_most(&f, 40).unwrap_err().to_string();
    assert!(
        e.contains("rec.csv:42:") && e.contains("more than 40 samples"),
        "{e}"
    );
}

#[test]
fn profiles_are_trapezoids_and_invert() {
    let p = Profile {
        t0_s: 2.0,
        length_mm: 10.0,
        speed_mm_s: 20.0,
        accel_mm_s2: 400.0,
    };
    // 0.05 s to 20 mm/s over 0.5 mm, 9 mm of cruise at 20 mm/s, 0.05 s down.
    assert!((p.duration_s() - (0.1 + 9.0 / 20.0)).abs() < 1e-12);
    assert!((p.s_at(2.05) - 0.5).abs() < 1e-12);
    assert!((p.s_at(2.3) - (0.5 + 20.0 * 0.25)).abs() < 1e-12);
    assert_eq!(p.s_at(1.0), 0.0);
    assert_eq!(p.s_at(9.0), 10.0);
    for s in [0.0, 0.1, 0.5, 3.0, 9.7, 10.0] {
        assert!((p.s_at(p.t_at(s)) - s).abs() < 1e-9, "{s}");
    }
    // Too short to reach the speed: a triangle.
    let tri = Profile {
        length_mm: 0.4,
        ..p
    };
    assert!((tri.duration_s() - 2.0 * (0.4f64 / 400.0).sqrt()).abs() < 1e-12);
    assert!((tri.s_at(tri.t0_s + tri.duration_s() / 2.0) - 0.2).abs() < 1e-12);
}

#[test]
fn the_speed_that_fills_the_time() {
    // Two runs of 500 mm at 16 mm/s with a = 800 mm/s²: each 500/16 + 16/800 s.
    let (v, a) = (16.0, 800.0);
    let time = 2.0 * (500.0 / v + v / a);
    assert!((solve_speed(&[500.0, 500.0], a, time) - v).abs() < 1e-9);
}

#[test]
fn a_ruler_with_the_machines_errors_on_it_is_read_true_through_them() {
    // A feed-in along x from 88 to 90 mm (relative to the table ball) at 16 mm/s on an axis
    // with a 2 µm, 10 mm-pitch cyclic error: D carries δ_x = A·sin(2π·x/P + φ), which
    // stretches the 2 mm ruler by up to 2πA/P = 1.3·10⁻³. Read through that error, the
    // speed is true again.
    let prof = Profile {
        t0_s: 0.5,
        length_mm: 2.0,
        speed_mm_s: 16.0,
        accel_mm_s2: 500.0,
    };
    let (amp_mm, pitch_mm, phase) = (2e-3, 10.0, 0.4);
    let cyclic = |x: f64| amp_mm * (std::f64::consts::TAU * x / pitch_mm + phase).sin();
    let t: Vec<f64> = (0..1500).map(|i| i as f64 * 1e-3).collect();
    let d: Vec<f64> = t
        .iter()
        .map(|&ti| {
            let x = 88.0 + prof.s_at(ti);
            x + cyclic(x)
        })
        .collect();
    let rec = Record::from_samples(FsPath::new("r.csv"), t, d);
    let cross = crossing(&rec, 0, 89.0, 1.0).unwrap();
    let error = |p: &[[f64; 3]]| p.iter().map(|q| cyclic(q[0])).collect::<Vec<_>>();
    let ruler = Ruler { error_mm: &error };
    let fit = |r: Option<&Ruler>| {
        fit_ramp(
            &rec,
            cross,
            [88.0, 0.0, 0.0],
            [90.0, 0.0, 0.0],
            88.0,
            90.0,
            16.0,
            0.25,
            0.25,
            r,
        )
        .unwrap()
        .profile
        .speed_mm_s
            / 16.0
            - 1.0
    };
    let (bent, true_read) = (fit(None), fit(Some(&ruler)));
    assert!(
        bent.abs() > 3e-4,
        "the cyclic error bends the ruler: {bent}"
    );
    assert!(true_read.abs() < 1e-5, "read through it: {true_read}");
}

#[test]
fn facts_combine_by_their_errors_and_a_disagreement_is_said() {
    let fact = |source, factor, sigma| FeedFact {
        source,
        circle: Some(0),
        factor,
        sigma,
    };
    // Two facts that agree: the weighted mean, the smaller σ wins.
    let f = combine(&[
        fact(FeedSource::Ramp, 1.0002, 2e-4),
        fact(FeedSource::ArcDurations, 1.0000, 5e-5),
    ])
    .unwrap();
    assert!((f.factor - (1.0002 * 25.0 + 1.0 * 400.0) / 425.0).abs() < 1e-9);
    assert!(f.note.is_none());
    // A ruler 10⁻³ off at σ 10⁻⁴ against arc durations at 5·10⁻⁵: said, and σ scaled up.
    let f = combine(&[
        fact(FeedSource::Ramp, 1.001, 1e-4),
        fact(FeedSource::ArcDurations, 1.0000, 5e-5),
    ])
    .unwrap();
    let note = f.note.unwrap();
    assert!(note.contains("ramp of circle 1 says 100.100"), "{note}");
    assert!(f.sigma > 3e-4, "{}", f.sigma);
    assert!(combine(&[]).is_none());
}

#[test]
fn a_ramp_fit_recovers_start_speed_and_acceleration() {
    // A feed-in of 2 mm from R 88 to 90 mm (xy, radial along x) at 16.667 mm/s, a = 500,
    // sampled at 1 kHz with 0.3 µm noise, dwells either side.
    let prof = Profile {
        t0_s: 1.2345,
        length_mm: 2.0,
        speed_mm_s: 1000.0 / 60.0,
        accel_mm_s2: 500.0,
    };
    let mut t = vec![];
    let mut d = vec![];
    let mut x: u64 = 7;
    for i in 0..3000 {
        let ti = i as f64 * 1e-3;
        x = x
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        let noise = ((x >> 11) as f64 / (1u64 << 53) as f64 - 0.5) * 1e-3;
        t.push(ti);
        d.push(88.0 + prof.s_at(ti) + noise);
    }
    let rec = Record::from_samples(FsPath::new("r.csv"), t, d);
    let cross = crossing(&rec, 0, 89.0, 1.0).unwrap();
    let r = fit_ramp(
        &rec,
        cross,
        [88.0, 0.0, 0.0],
        [90.0, 0.0, 0.0],
        88.0,
        90.0,
        1000.0 / 60.0,
        0.25,
        0.25,
        None,
    )
    .unwrap();
    assert!((r.profile.t0_s - prof.t0_s).abs() < 2e-4, "{:?}", r.profile);
    assert!((r.profile.speed_mm_s / prof.speed_mm_s - 1.0).abs() < 2e-3);
    assert!((r.profile.accel_mm_s2 / prof.accel_mm_s2 - 1.0).abs() < 0.1);
    assert!((r.profile.end_s() - prof.end_s()).abs() < 2e-4);
}
