//! On-chip accuracy (issues 1 and 9: "D computed by the core on the Cortex-M4F must match a host
//! f64 reference within 10 nm or 1 % of one count's step", with the extended instrument model). The
//! `accuracy` firmware program evaluates `geometry::Kernel` on the emulated Cortex-M4F over grids
//! of counts covering the frames' working range and streams (enc1, enc2, d_mm) as ordinary frames;
//! each grid is preceded by a `DeviceInfo` carrying the calibration it used: the default 2²³-count
//! instrument, one with every error term of the extended model non-zero, and seed 000's 20 000-count
//! instrument. Here every on-chip D is compared with the host's independent f64 reference
//! `geometry::distance_mm` of the same model.
use std::time::Duration;

use jdbb_core::calib::{Calibration, Direction, Param};
use jdbb_core::protocol::{Decoder, DeviceMsg};
use jdbb_tests::{chip_error_mm, qemu_available, qemu_elf, Qemu};

#[test]
fn on_chip_distance_matches_host_reference_within_budget() {
    let elf = qemu_elf("accuracy");
    if !qemu_available(&elf) {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("usart2.bin");
    let status = Qemu::run_to_exit(&elf, &out, Duration::from_secs(120));
    assert!(status.success(), "accuracy program failed: {status}");
    let bytes = std::fs::read(&out).unwrap();

    let mut decoder = Decoder::<{ jdbb_core::protocol::MAX_FRAME_LEN }>::new();
    // Per grid: its calibration, points, worst error (nm) and worst error/budget.
    let mut grids: Vec<(Calibration, usize, f64, f64)> = Vec::new();
    let mut corrupt = 0usize;
    decoder.feed::<DeviceMsg>(&bytes, |msg| match msg {
        Ok(DeviceMsg::Info(info)) => grids.push((info.calibration, 0, 0.0, 0.0)),
        Ok(DeviceMsg::Batch(batch)) => {
            let grid = grids.last_mut().expect("a DeviceInfo precedes every grid");
            for s in &batch.samples {
                let (err, budget) = chip_error_mm(&grid.0, s);
                assert!(
                    err <= budget,
                    "counts ({}, {}): chip {} mm, error {:.3} nm > budget {:.3} nm",
                    s.enc1,
                    s.enc2,
                    s.d_mm,
                    err * 1e6,
                    budget * 1e6
                );
                grid.1 += 1;
                grid.2 = grid.2.max(err * 1e6);
                grid.3 = grid.3.max(err / budget);
            }
        }
        Ok(other) => panic!("unexpected message {other:?}"),
        Err(_) => corrupt += 1,
    });
    assert_eq!(corrupt, 0, "corrupt frames from the accuracy program");
    assert_eq!(grids.len(), 3, "expected three calibrations");
    for (cal, n, _, _) in &grids {
        assert!(*n >= 6_000, "only {n} points for {cal:?}");
    }
    // The default instrument, and one with every error term of the extended model.
    assert_eq!(grids[0].0, Calibration::DEFAULT);
    let full = &grids[1].0;
    let every_term = Param::ALL.iter().all(|p| full.param(*p) != 0.0)
        && full.enc1.zero_count != 0
        && full.enc2.direction == Direction::Negative;
    assert!(every_term, "second grid lacks an error term: {full:?}");
    assert_eq!(grids[2].0.enc1.counts_per_rev, 20_000);
    let names = ["default 2^23", "every error term", "20 000 counts"];
    for ((_, n, nm, ratio), name) in grids.iter().zip(names) {
        println!(
            "on-chip accuracy, {name}: {n} points, max |D_chip − D_ref| = {nm:.3} nm, max error/budget = {ratio:.4}"
        );
    }
}
