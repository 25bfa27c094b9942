//! The board's clock start, the parts free of hardware: whether the crystal runs at the frequency
//! the firmware was built for ([`crystal_check`]), and the status LED's patterns ([`blink`]) that
//! report a clock that could not start.
//!
//! **Why measure the crystal.** The firmware programs the PLL for the crystal its build names
//! (`hse-…` features). A board with another crystal would run the PLL outside its range and the
//! core at a multiple of its rated clock (an 8 MHz build on a 25 MHz crystal: 300 MHz), so the
//! board measures the crystal against the internal oscillator (HSI) before the PLL starts: TIM11
//! captures `HSE_RTC` (the crystal divided by `RCC_CFGR.RTCPRE`) every 8th edge, counting HSI
//! cycles. HSI is factory-trimmed to ±1 % at 25 °C and within ±4 % over −10…85 °C (DS10314), so a
//! crystal within [`CRYSTAL_TOLERANCE_PERCENT`] of the build's is taken: this tells 8, 12, 16 and
//! 25 MHz apart, not 24 from 25 MHz.
//!
//! **Only a reading that is another supported crystal rejects the crystal** ([`crystal_verdict`]):
//! falling back to HSI costs USB (which needs ±0.25 %, HSI gives ±4 %), so a reading that is
//! neither the build's crystal nor another of [`SUPPORTED_CRYSTALS`] (a glitch, a capture that
//! went wrong) is treated like no reading at all: the crystal is used as built.

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

/// The crystals a build exists for (Hz) and how to build for each: the cargo feature, or the
/// default.
pub const SUPPORTED_CRYSTALS: [(u32, &str); 5] = [
    (8_000_000, "--features hse-8mhz"),
    (12_000_000, "--features hse-12mhz"),
    (16_000_000, "--features hse-16mhz"),
    (24_000_000, "--features hse-24mhz"),
    (25_000_000, "the default build (no hse- feature)"),
];

/// What a measurement of the crystal says about it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum CrystalVerdict {
    /// Within the tolerance of the build's crystal: use it.
    Build,
    /// Not the build's, but another supported crystal (its frequency, Hz, and how to build
    /// for it): do not use it (the PLL would run outside its range).
    Other(u32, &'static str),
    /// Neither the build's nor any supported crystal: the measurement is not trusted, the
    /// crystal is used as built (as when no edge could be measured).
    Nonsense,
}

impl CrystalVerdict {
    /// Whether the crystal drives the clocks after this verdict: all but another supported
    /// crystal (a nonsense reading is treated like none: the crystal is used as built).
    pub fn uses_crystal(self) -> bool {
        !matches!(self, CrystalVerdict::Other(..))
    }
}

/// The verdict on a crystal measured at `measured_hz` for a build for `build_hz`: the build's
/// crystal while the reading is within [`CRYSTAL_TOLERANCE_PERCENT`] of it (it wins a tie with a
/// neighbour, 24 against 25 MHz); otherwise the nearest other of [`SUPPORTED_CRYSTALS`] within
/// the tolerance; otherwise [`CrystalVerdict::Nonsense`].
pub fn crystal_verdict(measured_hz: u32, build_hz: u32) -> CrystalVerdict {
    if crystal_check(measured_hz, build_hz) {
        return CrystalVerdict::Build;
    }
    SUPPORTED_CRYSTALS
        .iter()
        .filter(|(hz, _)| *hz != build_hz && crystal_check(measured_hz, *hz))
        .min_by_key(|(hz, _)| hz.abs_diff(measured_hz))
        .map_or(CrystalVerdict::Nonsense, |&(hz, how)| {
            CrystalVerdict::Other(hz, how)
        })
}

/// The verdict when the crystal's divided edges came faster than the measurement could read
/// them: far faster than the build's. Another crystal if a supported one is faster than the
/// build's (the fastest: an overclocked PLL is what must not happen), else nonsense.
pub fn crystal_verdict_too_fast(build_hz: u32) -> CrystalVerdict {
    SUPPORTED_CRYSTALS
        .iter()
        .filter(|(hz, _)| !crystal_check(*hz, build_hz) && *hz > build_hz)
        .max_by_key(|(hz, _)| *hz)
        .map_or(CrystalVerdict::Nonsense, |&(hz, how)| {
            CrystalVerdict::Other(hz, how)
        })
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

/// The status LED's code for a panic during start-up (the firmware stops there instead of
/// resetting into the same panic again): a steady flicker, 100 ms on, 100 ms off — unlike the
/// 2 s patterns of [`blink`].
pub fn panic_blink(t_ms: u32) -> bool {
    t_ms % 200 < 100
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
    fn only_another_supported_crystal_is_rejected() {
        // Issue 32 §2: the crystal check falls back to HSI (no USB) only for a reading that is
        // another supported crystal; nonsense is treated like no reading.
        let measure = |true_hse: f64, hsi_error: f64, divider: u32| {
            let edges = 64 * 8;
            let seconds = f64::from(edges * divider) / true_hse;
            let cycles = (seconds * 16e6 * (1.0 + hsi_error)).round() as u32;
            crystal_hz(cycles, edges, divider, 16_000_000).unwrap()
        };
        for (build, _) in SUPPORTED_CRYSTALS {
            let div = build / 1_000_000;
            for err in [-0.04, -0.01, 0.0, 0.01, 0.04] {
                // The build's own crystal, at any HSI error.
                let hz = measure(f64::from(build), err, div);
                assert_eq!(
                    crystal_verdict(hz, build),
                    CrystalVerdict::Build,
                    "{build} {err}"
                );
                // Every other supported crystal far enough from the build's to tell apart.
                for (other, how) in SUPPORTED_CRYSTALS {
                    let hz = measure(f64::from(other), err, div);
                    if other.abs_diff(build) * 100 > build * 10 {
                        // 24 and 25 MHz are within the HSI's tolerance of each other: either.
                        let v = crystal_verdict(hz, build);
                        assert!(
                            v == CrystalVerdict::Other(other, how)
                                || matches!(v, CrystalVerdict::Other(o, _)
                                    if other >= 24_000_000 && o >= 24_000_000),
                            "{other} on a {build} build, HSI {err}: {v:?}"
                        );
                    }
                }
                // A reading that is no supported crystal: not trusted, not a rejection.
                for bogus in [5e6, 10e6, 20e6, 40e6, 100e3] {
                    let hz = measure(bogus, err, div);
                    assert_eq!(
                        crystal_verdict(hz, build),
                        CrystalVerdict::Nonsense,
                        "{bogus}"
                    );
                }
            }
        }
        assert_eq!(
            crystal_verdict(8_000_000, 25_000_000),
            CrystalVerdict::Other(8_000_000, "--features hse-8mhz")
        );
        // Too fast to read: the fastest supported crystal above the build's, if there is one.
        assert_eq!(
            crystal_verdict_too_fast(8_000_000),
            CrystalVerdict::Other(25_000_000, "the default build (no hse- feature)")
        );
        assert_eq!(
            crystal_verdict_too_fast(25_000_000),
            CrystalVerdict::Nonsense
        );
        assert_eq!(
            crystal_verdict_too_fast(24_000_000),
            CrystalVerdict::Nonsense
        );
    }

    #[test]
    fn the_init_panic_code_is_unlike_every_running_pattern() {
        // Ten flashes in a 2 s period (the running patterns have at most 4), all period long.
        let rises = |f: &dyn Fn(u32) -> bool| {
            (1..BLINK_PERIOD_MS).filter(|&t| !f(t - 1) && f(t)).count() + usize::from(f(0))
        };
        assert_eq!(rises(&panic_blink), 10);
        for flashes in 1..=4 {
            assert!(rises(&|t| blink(flashes, t)) <= 4);
        }
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
