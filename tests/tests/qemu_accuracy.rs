//! On-chip accuracy (issue: "D computed by the core on the Cortex-M4F must match a host f64
//! reference within 10 nm or 1 % of one count's step"). The `accuracy` firmware program evaluates
//! `geometry::Kernel` on the emulated Cortex-M4F over grids of counts covering the frames' working
//! range and streams (enc1, enc2, d_mm) as ordinary frames; each grid is preceded by a `DeviceInfo`
//! carrying the calibration it used. Here every on-chip D is compared with the host's independent
//! f64 reference `geometry::distance_mm`.
use std::time::Duration;

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
    let mut cal = None;
    let mut grids = 0usize;
    let mut n = 0usize;
    let mut corrupt = 0usize;
    let mut worst_err_nm = 0.0f64;
    let mut worst_ratio = 0.0f64;
    decoder.feed::<DeviceMsg>(&bytes, |msg| match msg {
        Ok(DeviceMsg::Info(info)) => {
            cal = Some(info.calibration);
            grids += 1;
        }
        Ok(DeviceMsg::Batch(batch)) => {
            let cal = cal.expect("a DeviceInfo precedes every grid");
            for s in &batch.samples {
                let (err, budget) = chip_error_mm(&cal, s);
                assert!(
                    err <= budget,
                    "counts ({}, {}): chip {} mm, error {:.3} nm > budget {:.3} nm",
                    s.enc1,
                    s.enc2,
                    s.d_mm,
                    err * 1e6,
                    budget * 1e6
                );
                worst_err_nm = worst_err_nm.max(err * 1e6);
                worst_ratio = worst_ratio.max(err / budget);
                n += 1;
            }
        }
        Ok(other) => panic!("unexpected message {other:?}"),
        Err(_) => corrupt += 1,
    });
    assert_eq!(corrupt, 0, "corrupt frames from the accuracy program");
    assert!(
        grids >= 2,
        "expected at least two calibrations, got {grids}"
    );
    assert!(n >= 10_000, "only {n} points compared");
    println!(
        "on-chip accuracy: {n} points over {grids} calibrations, max |D_chip − D_ref| = {worst_err_nm:.2} nm, \
         max error/budget = {worst_ratio:.3}"
    );
}
