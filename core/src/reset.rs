//! Why the device last started, from what survives a reset: the STM32F4's reset flags (`RCC_CSR`,
//! RM0383 §6.3.20) and a mark the firmware writes to uninitialised RAM just before it resets itself
//! after a panic or a hard fault. The board reads both once at start-up, clears them, and reports
//! the result in `DeviceInfo::reset_cause` at every connection.

use crate::protocol::ResetCause;

/// Mark left in uninitialised RAM by the panic handler before it resets the chip.
pub const MARK_PANIC: u32 = 0x5041_4e43; // "PANC"
/// Mark left in uninitialised RAM by the hard-fault handler before it resets the chip.
pub const MARK_FAULT: u32 = 0x4641_4c54; // "FALT"
/// What the board writes over the mark once read, so the next reset starts clean.
pub const MARK_NONE: u32 = 0;
/// Upper half of the mark the default interrupt handler leaves ("IR"): an interrupt without a
/// handler fired; the lower half is its IRQ number ([`mark_unhandled_irq`]).
const MARK_IRQ_TAG: u32 = 0x4952_0000;

/// The mark the default handler leaves for an interrupt without a handler: [`MARK_IRQ_TAG`] and
/// the IRQ number (negative for a core exception, as `cortex-m-rt`'s `DefaultHandler` gets it).
pub const fn mark_unhandled_irq(irqn: i16) -> u32 {
    MARK_IRQ_TAG | irqn as u16 as u32
}

/// `RCC_CSR` reset flags of the STM32F4 (bit numbers from RM0383 §6.3.20).
const CSR_BORRSTF: u32 = 1 << 25;
const CSR_PINRSTF: u32 = 1 << 26;
const CSR_PORRSTF: u32 = 1 << 27;
const CSR_SFTRSTF: u32 = 1 << 28;
const CSR_IWDGRSTF: u32 = 1 << 29;
const CSR_WWDGRSTF: u32 = 1 << 30;
const CSR_LPWRRSTF: u32 = 1 << 31;

/// The reset cause from the value of `RCC_CSR` at start-up and the RAM mark. The mark counts only
/// after a software reset without a power-on (RAM holds garbage after a power-on, and a mark of an
/// earlier crash must not survive a later pin reset: the board clears it at every start).
pub fn from_stm32f4(csr: u32, mark: u32) -> ResetCause {
    let mut bits = 0;
    for (flag, bit) in [
        (CSR_PINRSTF, ResetCause::PIN),
        (CSR_PORRSTF, ResetCause::POWER),
        (CSR_BORRSTF, ResetCause::BROWN_OUT),
        (CSR_SFTRSTF, ResetCause::SOFTWARE),
        (CSR_IWDGRSTF | CSR_WWDGRSTF, ResetCause::WATCHDOG),
        (CSR_LPWRRSTF, ResetCause::LOW_POWER),
    ] {
        if csr & flag != 0 {
            bits |= bit;
        }
    }
    let software_only = csr & CSR_SFTRSTF != 0 && csr & (CSR_PORRSTF | CSR_BORRSTF) == 0;
    if software_only {
        match mark {
            MARK_PANIC => bits |= ResetCause::PANIC,
            MARK_FAULT => bits |= ResetCause::FAULT,
            m if m & 0xffff_0000 == MARK_IRQ_TAG => bits |= ResetCause::FAULT,
            _ => {}
        }
    }
    ResetCause(bits)
}

/// The interrupt without a handler that made the firmware reset itself, from the same `RCC_CSR`
/// and RAM mark as [`from_stm32f4`] (reported with [`ResetCause::FAULT`]); `None` for any other
/// start.
pub fn unhandled_irq(csr: u32, mark: u32) -> Option<i16> {
    let software_only = csr & CSR_SFTRSTF != 0 && csr & (CSR_PORRSTF | CSR_BORRSTF) == 0;
    (software_only && mark & 0xffff_0000 == MARK_IRQ_TAG).then_some(mark as u16 as i16)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn power_on_sets_power_and_pin_and_ignores_ram() {
        // After power-on the F4 reports PORRSTF and PINRSTF; RAM is random, even a mark.
        let c = from_stm32f4(CSR_PORRSTF | CSR_PINRSTF, MARK_PANIC);
        assert_eq!(c, ResetCause(ResetCause::POWER | ResetCause::PIN));
        assert!(!c.crashed());
    }

    #[test]
    fn panic_and_fault_marks_need_a_software_reset() {
        let sw = CSR_SFTRSTF | CSR_PINRSTF; // SYSRESETREQ also pulses NRST
        let c = from_stm32f4(sw, MARK_PANIC);
        assert!(c.has(ResetCause::SOFTWARE | ResetCause::PANIC | ResetCause::PIN));
        assert!(c.crashed() && !c.has(ResetCause::FAULT));
        let c = from_stm32f4(sw, MARK_FAULT);
        assert!(c.has(ResetCause::SOFTWARE | ResetCause::FAULT) && !c.has(ResetCause::PANIC));
        // A probe's or the host's reset leaves no mark: not a crash.
        assert!(!from_stm32f4(sw, MARK_NONE).crashed());
        // Any other RAM word is not a mark.
        assert!(!from_stm32f4(sw, MARK_PANIC ^ 1).crashed());
        // A pin reset after a crash: the mark was cleared at the crash's start-up, and without
        // SFTRSTF it would not count anyway.
        assert_eq!(
            from_stm32f4(CSR_PINRSTF, MARK_PANIC),
            ResetCause(ResetCause::PIN)
        );
        // A brown-out during the reset: RAM is not trusted.
        assert!(!from_stm32f4(sw | CSR_BORRSTF, MARK_PANIC).crashed());
    }

    #[test]
    fn an_unhandled_interrupt_is_a_fault_with_its_number() {
        // Issue 32 §4: a stray interrupt resets through the default handler, not the watchdog.
        let sw = CSR_SFTRSTF | CSR_PINRSTF;
        for irqn in [0i16, 28, 85, -1, -14] {
            let mark = mark_unhandled_irq(irqn);
            let c = from_stm32f4(sw, mark);
            assert!(
                c.has(ResetCause::FAULT) && !c.has(ResetCause::WATCHDOG),
                "{irqn}"
            );
            assert_eq!(unhandled_irq(sw, mark), Some(irqn));
            // After a power-on the RAM word means nothing.
            assert_eq!(unhandled_irq(CSR_PORRSTF | CSR_PINRSTF, mark), None);
        }
        assert_eq!(unhandled_irq(sw, MARK_FAULT), None);
        assert_eq!(unhandled_irq(sw, MARK_PANIC), None);
        assert_eq!(unhandled_irq(sw, MARK_NONE), None);
    }

    #[test]
    fn watchdog_and_low_power_flags() {
        assert!(from_stm32f4(CSR_IWDGRSTF, 0).has(ResetCause::WATCHDOG));
        assert!(from_stm32f4(CSR_WWDGRSTF, 0).has(ResetCause::WATCHDOG));
        assert!(from_stm32f4(CSR_LPWRRSTF, 0).has(ResetCause::LOW_POWER));
        // RMVF (bit 24) and the LSI bits are not reset causes.
        assert_eq!(from_stm32f4(1 << 24 | 0b11, 0), ResetCause(0));
    }
}
