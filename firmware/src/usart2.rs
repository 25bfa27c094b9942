//! USART2 (PA2 TX / PA3 RX, AF7), register-level, for the QEMU build and its test programs.
//!
//! QEMU's STM32 USART model writes every byte to the host at once and keeps TXE set, and raises the
//! interrupt on RXNE when RXNEIE is set; on real silicon the same code works at 115 200 Bd, TX
//! non-blocking (a byte is only written when TXE is set).

use stm32f4xx_hal::pac;
use stm32f4xx_hal::rcc::{Enable, Reset};

const SR_RXNE: u32 = 1 << 5;
const SR_TXE: u32 = 1 << 7;
const SR_ORE: u32 = 1 << 3;
const CR1_RE: u32 = 1 << 2;
const CR1_TE: u32 = 1 << 3;
const CR1_RXNEIE: u32 = 1 << 5;
const CR1_UE: u32 = 1 << 13;

/// The UART link.
pub struct Usart2 {
    usart: pac::USART2,
}

impl Usart2 {
    /// Enable USART2 at 115 200 Bd from a `pclk1_hz` bus clock, 8N1, TX and RX, RX interrupt on.
    /// The pins PA2/PA3 must already be in AF7.
    pub fn new(usart: pac::USART2, pclk1_hz: u32) -> Self {
        unsafe {
            pac::USART2::enable_unchecked();
            pac::USART2::reset_unchecked();
        }
        let brr = (pclk1_hz + 115_200 / 2) / 115_200;
        usart.brr().write(|w| unsafe { w.bits(brr) });
        usart
            .cr1()
            .write(|w| unsafe { w.bits(CR1_UE | CR1_TE | CR1_RE | CR1_RXNEIE) });
        Usart2 { usart }
    }

    /// Write as many bytes as the transmitter takes without waiting; returns how many.
    #[inline]
    pub fn write(&mut self, bytes: &[u8]) -> usize {
        let mut n = 0;
        for &b in bytes {
            if self.usart.sr().read().bits() & SR_TXE == 0 {
                break;
            }
            self.usart.dr().write(|w| unsafe { w.bits(b as u32) });
            n += 1;
        }
        n
    }

    /// Write all bytes, waiting for the transmitter (test programs only: never from a task).
    pub fn write_all(&mut self, bytes: &[u8]) {
        let mut rest = bytes;
        while !rest.is_empty() {
            let n = self.write(rest);
            rest = &rest[n..];
        }
    }

    /// Move received bytes into `buf`; returns how many (0 when none is pending).
    #[inline]
    pub fn read(&mut self, buf: &mut [u8]) -> usize {
        let mut n = 0;
        while n < buf.len() {
            let sr = self.usart.sr().read().bits();
            if sr & (SR_RXNE | SR_ORE) == 0 {
                break;
            }
            // Reading DR after SR clears RXNE and an overrun flag alike.
            let b = self.usart.dr().read().bits() as u8;
            if sr & SR_RXNE != 0 {
                buf[n] = b;
                n += 1;
            }
        }
        n
    }
}
