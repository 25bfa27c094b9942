//! The board's clock start, the parts free of hardware: whether the crystal runs at the frequency
//! the firmware was built for ([`crystal_check`]), and the status LED's patterns ([`blink`]) that
//! report a clock that could not start.
//!
//! **Why measure the crystal.** The firmware programs the PLL for the crystal its build names
//! (`hse-…` features). A board with another crystal would run the PLL outside its range and the
//! core at a multiple of its rated clock (an 8 MHz build on a 25 MHz crystal: 300 MHz), so the
//! board measures the crystal against the internal oscillator (HSI) before the PLL starts: TIM11
//! captures `HSE_RTC` (the crystal divided by `RCC_CFGR.RTCPRE`) every 8th edge, counting HSI
//! cycles. HSI is factory-trimmed to ±1 % at 25 °C and within ±4 % from 0 to 85 °C (DS10314), so a
//! crystal within [`CRYSTAL_TOLERANCE_PERCENT`] of the build's is taken: this tells 8, 12, 16 and
//! 25 MHz apart, not 24 from 25 MHz.

/// How far the measured crystal may be from the build's frequency (%): the HSI's tolerance over
/// 0–85 °C (±4 %) and a margin.
pub const CRYSTAL_TOLERANCE_PERCENT: u64 = 5;

/// The crystal frequency measured (Hz) from `cycles` of the reference clock (`ref_hz`, the HSI)
/// counted over `edges` edges of the crystal divided by `divider`; `None` for no cycles.
pub fn crystal_hz(cycles: u32, edges: u32, divider: u32, ref_hz: u32) -> Option<u32> {
    if cycles == 0 {
        return None;
    }
    let hz = u64::from(edges) * u64::from(divider) * u64::from(ref_hz) / u64::from(cycles);
    u32::try_from(hz).ok()
}

/// Whether a crystal measured at `measured_hz` is the build's `expected_hz` (within
/// [`CRYSTAL_TOLERANCE_PERCENT`]).
pub fn crystal_check(measured_hz: u32, expected_hz: u32) -> bool {
    let (m, e) = (u64::from(measured_hz), u64::from(expected_hz));
    m.abs_diff(e) * 100 <= e * CRYSTAL_TOLERANCE_PERCENT
}

/// Length of one status-LED pattern (ms): `flashes` short flashes, then dark until the next.
pub const BLINK_PERIOD_MS: u32 = 2_000;
const FLASH_ON_MS: u32 = 150;
const FLASH_PITCH_MS: u32 = 400;

/// Whether the status LED is lit at `t_ms` in the pattern of `flashes` flashes every
/// [`BLINK_PERIOD_MS`] (the board's LED: 1 = running, 2 = no crystal, or not the build's,
/// running on the internal oscillator, 3 = the PLL did not lock, 4 = the internal oscillator did
/// not answer). Counting the flashes must be easy by eye: 150 ms on, 250 ms off, at most 4 in a
/// 2 s period.
pub fn blink(flashes: u32, t_ms: u32) -> bool {
    let t = t_ms % BLINK_PERIOD_MS;
    t / FLASH_PITCH_MS < flashes.min(4) && t % FLASH_PITCH_MS < FLASH_ON_MS
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_crystal_is_measured_and_a_wrong_one_is_refused() {
        // The board's measurement: 64 captures of every 8th edge of HSE / 25 (1 MHz), counted in
        // cycles of a 16 MHz HSI: 512 µs, 8 192 cycles.
        let measure = |true_hse: f64, hsi_error: f64, divider: u32| {
            let edges = 64 * 8;
            let seconds = f64::from(edges * divider) / true_hse;
            let cycles = (seconds * 16e6 * (1.0 + hsi_error)).round() as u32;
            crystal_hz(cycles, edges, divider, 16_000_000).unwrap()
        };
        assert_eq!(measure(25e6, 0.0, 25), 25_000_000);
        // The build's crystal passes over the HSI's whole 0–85 °C range.
        for err in [-0.04, -0.01, 0.0, 0.01, 0.04] {
            assert!(crystal_check(measure(25e6, err, 25), 25_000_000), "{err}");
            assert!(crystal_check(measure(8e6, err, 8), 8_000_000), "{err}");
        }
        // Another crystal does not (the divider is the build's: 25 for a 25 MHz build).
        for (hse, build, div) in [
            (8e6, 25e6, 25),
            (25e6, 8e6, 8),
            (12e6, 16e6, 16),
            (16e6, 12e6, 12),
        ] {
            for err in [-0.04, 0.0, 0.04] {
                let hz = measure(hse, err, div);
                assert!(!crystal_check(hz, build as u32), "{hse} as {build}: {hz}");
            }
        }
        assert_eq!(crystal_hz(0, 8, 25, 16_000_000), None);
    }

    #[test]
    fn blink_patterns_flash_the_number_of_times_and_repeat() {
        for flashes in 1..=4u32 {
            // Count the dark → lit transitions over 3 periods, at 1 ms steps.
            let lit: std::vec::Vec<bool> = (0..3 * BLINK_PERIOD_MS)
                .map(|t| blink(flashes, t))
                .collect();
            let rises = lit.windows(2).filter(|w| !w[0] && w[1]).count() + usize::from(lit[0]);
            assert_eq!(rises as u32, 3 * flashes, "{flashes} flashes");
            // Each flash is 150 ms, the gap after the last one at least 400 ms.
            assert_eq!(lit.iter().filter(|&&l| l).count() as u32, 3 * flashes * 150);
            let last_off = (0..BLINK_PERIOD_MS)
                .rev()
                .find(|&t| blink(flashes, t))
                .unwrap();
            assert!(BLINK_PERIOD_MS - last_off > 400, "{flashes}: {last_off}");
        }
        assert!((0..BLINK_PERIOD_MS).all(|t| !blink(0, t)));
    }
}
