//! A volumetric record (`jdbb plan --volumetric`: xy cones at 0, D/3 and 2D/3, zx and yz 220°
//! arcs, moves along the shell between them) played on the tests' independent G-code machine
//! with a feed override, an unknown start and a clock off by ppm, and synchronised from D alone
//! across all its elements (`jdbb::volumetric::elements`).
mod planned;

use planned::read_back;

use jdbb::plan::{write_program, Dialect as PlanDialect, PlanSpec, Plane};
use jdbb::sync::synchronise;
use jdbb::volumetric::elements::elements;
use jdbb::volumetric::plan::{plan as volumetric, VolumetricSpec};
use jdbb_core::Calibration;
use jdbb_tests::gmachine::{Dialect, SimConfig, Simulation};

const CENTRE: [f64; 3] = [100.0, 50.0, -20.0];

#[test]
fn every_element_is_found_in_order_with_its_start_and_feed() {
    let spec = VolumetricSpec {
        distances_mm: vec![90.0],
        heights_mm: vec![],
        base: PlanSpec::machine_test(
            &[1.0],
            &[0.0],
            Plane::Xy,
            1000.0,
            CENTRE,
            PlanDialect::Linuxcnc,
        ),
    };
    let p = volumetric(&spec, &Calibration::DEFAULT).unwrap();
    let mut cfg = SimConfig::new(Dialect::LinuxCnc, CENTRE);
    cfg.machine.feed_override_pct = 97.0;
    cfg.instrument.clock_ppm = 40.0;
    cfg.instrument.start_delay_s = 3.0;
    cfg.instrument.noise_um = 0.2;
    cfg.instrument.sample_rate_hz = 100.0;
    let rec = Simulation::new(&write_program(&p, PlanDialect::Linuxcnc), cfg)
        .unwrap()
        .run()
        .unwrap();
    let r = read_back(&rec);
    let sync = synchronise(&p, &r).unwrap();
    let found = elements(&p, &sync);
    // The plan's five elements, in program order, with their planes and heights.
    let want = [
        (Plane::Xy, 0.0),
        (Plane::Xy, 30.0),
        (Plane::Xy, 60.0),
        (Plane::Zx, 0.0),
        (Plane::Yz, 0.0),
    ];
    assert_eq!(found.len(), want.len(), "{found:?}");
    // The feed as the device's clock measures it: a clock fast by ppm sees the motion slower.
    let t = &rec.truth;
    let feed = 1000.0 * t.feed_factor / (1.0 + 1e-6 * t.clock_ppm);
    let mut last_s = f64::NEG_INFINITY;
    for (k, (e, (plane, h))) in found.iter().zip(want).enumerate() {
        assert_eq!((e.circle, e.plane), (k, plane), "{e:?}");
        assert!((e.height_mm - h).abs() < 1e-9, "{e:?}");
        assert!(
            (e.feed_mm_min / feed - 1.0).abs() < 1e-3,
            "element {k}: {} mm/min vs {feed}",
            e.feed_mm_min
        );
        // Each starts after the one before and before its own data arcs.
        let data_s = sync.circles[k].data[0].t_start_s;
        assert!(e.start_s > last_s && e.start_s < data_s, "{e:?}");
        assert!(e.samples > 0, "{e:?}");
        last_s = data_s;
    }
    let start_us = sync.t0_us + 1e6 * sync.cycle_start_s;
    assert!(
        (start_us - t.cycle_start_us).abs() < 20_000.0,
        "cycle start {start_us} µs vs {} µs",
        t.cycle_start_us
    );
}
