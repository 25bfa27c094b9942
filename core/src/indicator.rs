//! The status LED's codes, played on any `embedded_hal::digital::OutputPin` with any
//! `embedded_hal::delay::DelayNs` (embedded-hal 1.0): the board supplies its LED pin and a
//! delay, this module decides what the LED shows. Host tests drive it through fakes that record
//! the pattern.
//!
//! The patterns themselves are [`crate::clock::blink`] (1–4 flashes every 2 s) and
//! [`crate::clock::panic_blink`] (the start-up panic's flicker); [`LedCode`] names which one
//! stands for what, [`ClockFault`] maps the clock start's failures to their code.

use embedded_hal::delay::DelayNs;
use embedded_hal::digital::{OutputPin, PinState};

use crate::clock::{blink, panic_blink};

/// Why the clocks did not start as built (the board's clock start, see [`crate::clock`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum ClockFault {
    /// No crystal, or another supported crystal than the build's: running on the internal
    /// oscillator (no USB).
    NoCrystal,
    /// The PLL did not lock: nothing runs.
    PllNoLock,
    /// The internal oscillator or the clock switch did not answer: nothing runs.
    HsiNoAnswer,
}

/// What the status LED shows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum LedCode {
    /// All well: one flash every 2 s.
    Running,
    /// A clock fault: its number of flashes every 2 s ([`LedCode::flashes`]).
    Clock(ClockFault),
    /// A panic during start-up: a steady 5 Hz flicker (100 ms on, 100 ms off).
    InitPanic,
}

impl LedCode {
    /// Flashes every 2 s (0 for the start-up panic's flicker, which is no counted pattern).
    pub const fn flashes(self) -> u32 {
        match self {
            LedCode::Running => 1,
            LedCode::Clock(ClockFault::NoCrystal) => 2,
            LedCode::Clock(ClockFault::PllNoLock) => 3,
            LedCode::Clock(ClockFault::HsiNoAnswer) => 4,
            LedCode::InitPanic => 0,
        }
    }

    /// The code while running: [`LedCode::Running`] on the crystal, else
    /// [`ClockFault::NoCrystal`] (on the internal oscillator).
    pub const fn running(on_crystal: bool) -> LedCode {
        if on_crystal {
            LedCode::Running
        } else {
            LedCode::Clock(ClockFault::NoCrystal)
        }
    }

    /// Whether the LED is lit at `t_ms` in this code's pattern.
    pub fn lit(self, t_ms: u32) -> bool {
        match self {
            LedCode::InitPanic => panic_blink(t_ms),
            code => blink(code.flashes(), t_ms),
        }
    }
}

/// The status LED on a pin; `active_low` for an LED lit by driving the pin low (the Black Pill's
/// PC13).
pub struct Indicator<P> {
    pin: P,
    active_low: bool,
}

impl<P: OutputPin> Indicator<P> {
    /// The LED on `pin`, left as it is (nothing is driven until [`Indicator::set`],
    /// [`Indicator::show`] or [`Indicator::play`]).
    pub const fn new(pin: P, active_low: bool) -> Self {
        Indicator { pin, active_low }
    }

    /// Light the LED or not (a pin error is ignored: the LED is only a hint).
    pub fn set(&mut self, lit: bool) {
        let _ = self.pin.set_state(PinState::from(lit != self.active_low));
    }

    /// Show `code` as it is at `t_ms` (called from a loop: the idle loop's clock).
    pub fn show(&mut self, code: LedCode, t_ms: u32) {
        self.set(code.lit(t_ms));
    }

    /// Play `code` for `ms` milliseconds from `t_ms` in steps of 1 ms timed by `delay`, calling
    /// `feed` (the watchdog) at every step; the time reached. For the loops that never return (a
    /// clock fault, a panic during start-up), which call it forever.
    pub fn play<D: DelayNs>(
        &mut self,
        delay: &mut D,
        code: LedCode,
        t_ms: u32,
        ms: u32,
        mut feed: impl FnMut(),
    ) -> u32 {
        let mut t = t_ms;
        for _ in 0..ms {
            feed();
            self.show(code, t);
            delay.delay_ms(1);
            t = t.wrapping_add(1);
        }
        t
    }

    /// The pin back.
    pub fn release(self) -> P {
        self.pin
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::clock::BLINK_PERIOD_MS;
    use core::convert::Infallible;
    use std::cell::RefCell;
    use std::rc::Rc;
    use std::vec::Vec;

    /// What happened, in order: the pin driven high or low, a wait (ns), a watchdog feed.
    #[derive(Debug, Clone, Copy, PartialEq)]
    enum Ev {
        Pin(bool),
        Wait(u64),
        Feed,
    }
    type Log = Rc<RefCell<Vec<Ev>>>;

    struct FakePin(Log);
    impl embedded_hal::digital::ErrorType for FakePin {
        type Error = Infallible;
    }
    impl OutputPin for FakePin {
        fn set_low(&mut self) -> Result<(), Infallible> {
            self.0.borrow_mut().push(Ev::Pin(false));
            Ok(())
        }
        fn set_high(&mut self) -> Result<(), Infallible> {
            self.0.borrow_mut().push(Ev::Pin(true));
            Ok(())
        }
    }

    struct FakeDelay(Log);
    impl DelayNs for FakeDelay {
        fn delay_ns(&mut self, ns: u32) {
            self.0.borrow_mut().push(Ev::Wait(u64::from(ns)));
        }
    }

    /// Play `code` for `ms` on an LED (`active_low` as the Black Pill's) and return, per
    /// millisecond of delay, whether the LED was lit during it, and the number of feeds.
    fn record(code: LedCode, ms: u32, active_low: bool) -> (Vec<bool>, usize) {
        let log: Log = Rc::default();
        let mut led = Indicator::new(FakePin(log.clone()), active_low);
        let mut delay = FakeDelay(log.clone());
        let end = led.play(&mut delay, code, 0, ms, || log.borrow_mut().push(Ev::Feed));
        assert_eq!(end, ms);
        let log = log.borrow();
        let mut level = active_low;
        let mut lit = Vec::new();
        let mut waited_ns = 0u64;
        for ev in log.iter() {
            match *ev {
                Ev::Pin(l) => level = l,
                Ev::Wait(ns) => {
                    waited_ns += ns;
                    while waited_ns >= 1_000_000 {
                        waited_ns -= 1_000_000;
                        lit.push(level != active_low);
                    }
                }
                Ev::Feed => {}
            }
        }
        assert_eq!(waited_ns, 0, "the delay is whole milliseconds");
        let feeds = log.iter().filter(|e| **e == Ev::Feed).count();
        (lit, feeds)
    }

    /// The lit stretches of a recording: (start ms, length ms).
    fn flashes(lit: &[bool]) -> Vec<(usize, usize)> {
        let mut out = Vec::new();
        let mut start = None;
        for (t, &l) in lit.iter().chain([false].iter()).enumerate() {
            match (l, start) {
                (true, None) => start = Some(t),
                (false, Some(s)) => {
                    out.push((s, t - s));
                    start = None;
                }
                _ => {}
            }
        }
        out
    }

    #[test]
    fn each_clock_fault_plays_its_code_on_the_pin() {
        // Issue 34: the LED code of each clock fault, through a fake OutputPin and DelayNs, as
        // the pin was driven: n flashes of 150 ms, 400 ms apart, every 2 s, the watchdog fed every
        // millisecond.
        for (fault, n) in [
            (ClockFault::NoCrystal, 2),
            (ClockFault::PllNoLock, 3),
            (ClockFault::HsiNoAnswer, 4),
        ] {
            for active_low in [true, false] {
                let ms = 2 * BLINK_PERIOD_MS;
                let (lit, feeds) = record(LedCode::Clock(fault), ms, active_low);
                assert_eq!(lit.len() as u32, ms);
                assert_eq!(feeds as u32, ms, "{fault:?}: the watchdog fed every ms");
                let expected: Vec<(usize, usize)> = (0..2)
                    .flat_map(|p| (0..n).map(move |k| (p * 2000 + k * 400, 150)))
                    .collect();
                assert_eq!(flashes(&lit), expected, "{fault:?} active_low {active_low}");
            }
        }
        let (lit, _) = record(LedCode::Running, BLINK_PERIOD_MS, true);
        assert_eq!(flashes(&lit), [(0, 150)]);
    }

    #[test]
    fn the_start_up_panic_flickers_unlike_any_clock_code() {
        let (lit, _) = record(LedCode::InitPanic, 1000, true);
        let f = flashes(&lit);
        assert_eq!(f.len(), 5);
        assert!(f
            .iter()
            .enumerate()
            .all(|(k, &(s, l))| s == 200 * k && l == 100));
        // Every code is told apart by its flashes in a 2 s period.
        let codes = [
            LedCode::Running,
            LedCode::Clock(ClockFault::NoCrystal),
            LedCode::Clock(ClockFault::PllNoLock),
            LedCode::Clock(ClockFault::HsiNoAnswer),
            LedCode::InitPanic,
        ];
        let counts: Vec<usize> = codes
            .iter()
            .map(|&c| flashes(&record(c, BLINK_PERIOD_MS, true).0).len())
            .collect();
        assert_eq!(counts, [1, 2, 3, 4, 10]);
    }

    #[test]
    fn a_crystal_that_is_another_supported_one_shows_two_flashes() {
        // Issue 34: the crystal measured as the board does (every 8th edge of HSE / (build MHz),
        // 64 captures, counted in cycles of a 16 MHz HSI that is 3 % fast), its verdict, and the
        // LED code the board then shows, played on a fake pin.
        let reading = |true_hz: f64, build_hz: u32| {
            let div = build_hz / 1_000_000;
            let edges = 64 * 8;
            let cycles = (f64::from(edges * div) / true_hz * 16e6 * 1.03).round() as u32;
            crate::clock::crystal_hz(cycles, edges, div, 16_000_000).unwrap()
        };
        let shown = |true_hz: f64, build_hz: u32| {
            let verdict = crate::clock::crystal_verdict(reading(true_hz, build_hz), build_hz);
            let code = LedCode::running(verdict.uses_crystal());
            (
                verdict,
                flashes(&record(code, BLINK_PERIOD_MS, true).0).len(),
            )
        };
        // An 8 MHz crystal on a board built for 25 MHz: refused, the internal oscillator, two
        // flashes.
        let (v, n) = shown(8e6, 25_000_000);
        assert_eq!(
            v,
            crate::clock::CrystalVerdict::Other(8_000_000, "--features hse-8mhz")
        );
        assert_eq!(n, 2);
        // A 25 MHz crystal on a 12 MHz build (read as 24.3 MHz with this HSI: 24 or 25 MHz,
        // either is refused): the PLL would run at twice its rating.
        let (v, n) = shown(25e6, 12_000_000);
        assert!(
            matches!(v, crate::clock::CrystalVerdict::Other(hz, _) if hz >= 24_000_000),
            "{v:?}"
        );
        assert_eq!(n, 2);
        // The build's crystal, and a reading that is no supported crystal (not trusted, used as
        // built): 1 flash.
        assert_eq!(
            shown(25e6, 25_000_000),
            (crate::clock::CrystalVerdict::Build, 1)
        );
        assert_eq!(
            shown(10e6, 25_000_000),
            (crate::clock::CrystalVerdict::Nonsense, 1)
        );
    }
}
