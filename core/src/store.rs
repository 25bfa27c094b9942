//! The calibration kept in NOR flash across power cycles: a versioned, CRC-checked append log over
//! two erase blocks of any [`NorFlash`](embedded_storage::nor_flash::NorFlash), blocking, no
//! allocation.
//!
//! **Why not a key-value crate.** `sequential-storage` needs at least two erase pages for a map,
//! and the STM32F411's HAL erases in 128 KiB pages: 256 KiB of the 512 KiB F411xE, none on the
//! 256 KiB F411xC; it is also async only. One record type needs no map: this log takes exactly
//! two erase blocks, whatever their size.
//!
//! **Layout.** The region is two blocks of `block` bytes (a multiple of the flash's erase size and
//! of [`SLOT`]), each an array of [`SLOT`]-byte slots. A stored calibration is one slot:
//!
//! | bytes | field |
//! |---|---|
//! | 0..4 | magic `JDBC` |
//! | 4 | format version [`FORMAT_VERSION`] (the postcard layout of [`Calibration`]) |
//! | 5 | 0 |
//! | 6..8 | payload length n, u16 LE |
//! | 8..12 | sequence number, u32 LE, one more than the newest record's |
//! | 12..12+n | the calibration, postcard |
//! | 12+n..16+n | CRC-32C of bytes 0..12+n, LE |
//! | rest | erased (0xFF) |
//!
//! **Reading** ([`CalStore::open`]) scans both blocks and takes the valid record (magic, known
//! version, CRC, and a calibration that passes [`Calibration::validate`]) with the highest
//! sequence number. Anything else in a slot — a write cut by a power loss, a half-erased block,
//! another format version — is skipped.
//!
//! **Writing** ([`CalStore::store`]) programs the next slot that is still erased after the newest
//! record, in the newest record's block. When that block is full it erases the *other* block and
//! writes there: the newest record is never erased before its successor is complete, so a power
//! loss at any moment leaves either the old or the new calibration.
//!
//! **Erasing ahead** ([`CalStore::erase_spare`]). Once the log has moved to a block, the other
//! block (the *spare*) holds only superseded records and may be erased at any time. A device
//! erases it when an erase costs nothing (at power-up, while it is not sampling); the store that
//! fills the current block then starts the spare with no erase, a write only. An erase is slow
//! (2–4 s for the STM32F411's 128 KiB sectors) and on a single-bank flash it stalls the whole CPU,
//! so this takes it out of the command path. A store that finds the spare not erased (512 stores
//! without a chance to erase ahead) still erases it itself ([`CalStore::store_would_erase`] says
//! so beforehand). Wear: one erase per
//! `block / SLOT` stores, alternating between the two blocks (with 128 KiB blocks, 512 stores per
//! erase; the F411's 10 000 erase cycles then last 10 million stores).
use embedded_storage::nor_flash::NorFlash;

use crate::calib::Calibration;
use crate::protocol::CalKept;

/// Bytes per record slot (a multiple of every write size in use: 1, 4, 8, 16, 32).
pub const SLOT: usize = 256;

/// Version of the record's payload layout: bump it when [`Calibration`]'s postcard form changes;
/// records of another version are ignored.
pub const FORMAT_VERSION: u8 = 1;

const MAGIC: [u8; 4] = *b"JDBC";
const HEADER: usize = 12;
const CRC32C: crc::Crc<u32> = crc::Crc::<u32>::new(&crc::CRC_32_ISCSI);

/// Why the store failed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum StoreError<E> {
    /// Reading or programming the flash failed (its own error).
    Flash(E),
    /// Erasing a block failed (the flash's own error).
    Erase(E),
    /// The region does not fit the flash: blocks not a multiple of the erase size and of
    /// [`SLOT`], [`SLOT`] not a multiple of the write and read sizes, or beyond the capacity.
    Geometry,
    /// The calibration does not fit a slot (cannot happen with [`FORMAT_VERSION`] 1).
    TooLarge,
    /// The flash accepted the record, but reading it back gave other bytes (a write that did
    /// not take: worn, protected or failing flash, or a driver that missed an error).
    ReadBack,
}

impl<E> StoreError<E> {
    /// What the device reports to the host for a store that failed this way.
    pub fn kept(&self) -> CalKept {
        match self {
            StoreError::Flash(_) | StoreError::TooLarge => CalKept::WriteFailed,
            StoreError::Erase(_) => CalKept::EraseFailed,
            StoreError::Geometry => CalKept::NoRoom,
            StoreError::ReadBack => CalKept::ReadBackDiffers,
        }
    }
}

/// What the device reports to the host for the result of [`CalStore::store`].
pub fn kept<E>(result: &Result<(), StoreError<E>>) -> CalKept {
    match result {
        Ok(()) => CalKept::Stored,
        Err(e) => e.kept(),
    }
}

/// A record found in the log.
#[derive(Debug, Clone, Copy)]
struct Found {
    block: u32,
    slot: u32,
    seq: u32,
    cal: Calibration,
}

/// The calibration store over two blocks of `flash` from `base` (see the module docs).
#[derive(Debug)]
pub struct CalStore<F> {
    flash: F,
    base: u32,
    block: u32,
    newest: Option<Found>,
    /// The spare block (the one the newest record is not in) is known to be erased.
    spare_erased: bool,
}

impl<F: NorFlash> CalStore<F> {
    /// Open the store over `[base, base + 2·block)` of `flash` and find the newest valid record.
    pub fn open(mut flash: F, base: u32, block: u32) -> Result<Self, StoreError<F::Error>> {
        let b = block as usize;
        let fits = b > 0
            && b.is_multiple_of(F::ERASE_SIZE)
            && b.is_multiple_of(SLOT)
            && SLOT.is_multiple_of(F::WRITE_SIZE)
            && SLOT.is_multiple_of(F::READ_SIZE)
            && (base as usize).is_multiple_of(F::ERASE_SIZE)
            && (base as usize)
                .checked_add(2 * b)
                .is_some_and(|end| end <= flash.capacity());
        if !fits {
            return Err(StoreError::Geometry);
        }
        let mut newest: Option<Found> = None;
        let mut buf = [0u8; SLOT];
        let mut erased = [true; 2];
        for blk in 0..2 {
            for slot in 0..block / SLOT as u32 {
                flash
                    .read(base + blk * block + slot * SLOT as u32, &mut buf)
                    .map_err(StoreError::Flash)?;
                erased[blk as usize] &= buf.iter().all(|&b| b == 0xFF);
                if let Some((seq, cal)) = parse(&buf) {
                    if newest.is_none_or(|n| seq > n.seq) {
                        newest = Some(Found {
                            block: blk,
                            slot,
                            seq,
                            cal,
                        });
                    }
                }
            }
        }
        let current = newest.map_or(0, |n| n.block);
        Ok(CalStore {
            flash,
            base,
            block,
            newest,
            spare_erased: erased[1 - current as usize],
        })
    }

    /// The block the log writes into: the newest record's (block 0 while there is none).
    fn current_block(&self) -> u32 {
        self.newest.map_or(0, |n| n.block)
    }

    /// Erase the spare block (the one the newest record is not in) if it is not erased already,
    /// so that no later [`Self::store`] has to erase; returns whether it erased. Safe at any time:
    /// the spare holds only superseded records.
    pub fn erase_spare(&mut self) -> Result<bool, StoreError<F::Error>> {
        if self.spare_erased {
            return Ok(false);
        }
        let from = self.base + (1 - self.current_block()) * self.block;
        self.flash
            .erase(from, from + self.block)
            .map_err(StoreError::Erase)?;
        self.spare_erased = true;
        Ok(true)
    }

    /// Whether the next [`Self::store`] would erase a block (the current block is full and the
    /// spare was not erased ahead).
    pub fn store_would_erase(&mut self) -> Result<bool, StoreError<F::Error>> {
        let (block, first) = self.next_in_current();
        Ok(!self.spare_erased && self.erased_slot(block, first)?.is_none())
    }

    /// The current block and the first slot after the newest record in it.
    fn next_in_current(&self) -> (u32, u32) {
        match self.newest {
            Some(nw) => (nw.block, nw.slot + 1),
            None => (0, 0),
        }
    }

    /// The calibration stored last, if any record is valid.
    pub fn load(&self) -> Option<Calibration> {
        self.newest.map(|n| n.cal)
    }

    /// Store `cal` as the newest record (see the module docs for what a power loss leaves), and
    /// read it back: `Ok` only when the flash holds exactly the record written
    /// ([`StoreError::ReadBack`] otherwise; the calibration stored before stays the newest).
    pub fn store(&mut self, cal: &Calibration) -> Result<(), StoreError<F::Error>> {
        let seq = self.newest.map_or(0, |n| n.seq.wrapping_add(1));
        let mut rec = [0xFFu8; SLOT];
        let n = postcard::to_slice(cal, &mut rec[HEADER..SLOT - 4])
            .map_err(|_| StoreError::TooLarge)?
            .len();
        rec[..4].copy_from_slice(&MAGIC);
        rec[4] = FORMAT_VERSION;
        rec[5] = 0;
        rec[6..8].copy_from_slice(&(n as u16).to_le_bytes());
        rec[8..12].copy_from_slice(&seq.to_le_bytes());
        let crc = CRC32C.checksum(&rec[..HEADER + n]);
        rec[HEADER + n..HEADER + n + 4].copy_from_slice(&crc.to_le_bytes());

        let (block, first) = self.next_in_current();
        let slot = match self.erased_slot(block, first)? {
            Some(s) => (block, s),
            None => {
                // This block is full (or torn to the end): start the other one, erased ahead or
                // now. The newest record stays where it is until the next switch.
                self.erase_spare()?;
                (1 - block, 0)
            }
        };
        let at = self.base + slot.0 * self.block + slot.1 * SLOT as u32;
        // Only the record's bytes, rounded up to the write size (the rest of the slot stays
        // erased, and a write that completes is a complete record).
        let len = (HEADER + n + 4).div_ceil(F::WRITE_SIZE) * F::WRITE_SIZE;
        self.flash
            .write(at, &rec[..len])
            .map_err(StoreError::Flash)?;
        // Only a record read back equal counts as kept: a write whose error was missed, or that
        // did not take, must not be reported as stored.
        let mut back = [0u8; SLOT];
        self.flash
            .read(at, &mut back[..len])
            .map_err(StoreError::Flash)?;
        if back[..len] != rec[..len] {
            return Err(StoreError::ReadBack);
        }
        if slot.0 != block {
            // The log moved: the block it left is the spare now, full of old records.
            self.spare_erased = false;
        }
        self.newest = Some(Found {
            block: slot.0,
            slot: slot.1,
            seq,
            cal: *cal,
        });
        Ok(())
    }

    /// The flash, back.
    pub fn into_inner(self) -> F {
        self.flash
    }

    /// The first slot from `first` in `block` whose bytes are all erased.
    fn erased_slot(&mut self, block: u32, first: u32) -> Result<Option<u32>, StoreError<F::Error>> {
        let mut buf = [0u8; SLOT];
        for slot in first..self.block / SLOT as u32 {
            self.flash
                .read(
                    self.base + block * self.block + slot * SLOT as u32,
                    &mut buf,
                )
                .map_err(StoreError::Flash)?;
            if buf.iter().all(|&b| b == 0xFF) {
                return Ok(Some(slot));
            }
        }
        Ok(None)
    }
}

/// A slot's record, if it is a valid one of this format.
fn parse(buf: &[u8; SLOT]) -> Option<(u32, Calibration)> {
    if buf[..4] != MAGIC || buf[4] != FORMAT_VERSION || buf[5] != 0 {
        return None;
    }
    let n = u16::from_le_bytes([buf[6], buf[7]]) as usize;
    if HEADER + n + 4 > SLOT {
        return None;
    }
    let crc = u32::from_le_bytes(buf[HEADER + n..HEADER + n + 4].try_into().ok()?);
    if CRC32C.checksum(&buf[..HEADER + n]) != crc {
        return None;
    }
    let seq = u32::from_le_bytes([buf[8], buf[9], buf[10], buf[11]]);
    let (cal, rest) = postcard::take_from_bytes::<Calibration>(&buf[HEADER..HEADER + n]).ok()?;
    (rest.is_empty() && cal.validate().is_ok()).then_some((seq, cal))
}

/// A flash controller whose error flags stay set until cleared, and fail every later operation
/// while set (the STM32F4's `FLASH_SR`: the HAL fails an operation on any flag, a leftover one
/// included, and clears none). The ROM bootloader can leave one set before a DFU `:leave` (not a
/// reset), and a failed operation leaves its own.
pub trait StickyErrors {
    /// Clear every error flag (and bring the controller to the state an operation expects).
    fn clear_errors(&mut self);
}

/// A [`NorFlash`] whose leftover error flags are cleared before every erase and program
/// ([`StickyErrors`]): an operation fails only on an error of its own, which it reports (the
/// flag then stays set until the next operation clears it).
#[derive(Debug)]
pub struct ClearedFlags<F>(pub F);

impl<F: NorFlash> embedded_storage::nor_flash::ErrorType for ClearedFlags<F> {
    type Error = F::Error;
}

impl<F: NorFlash> embedded_storage::nor_flash::ReadNorFlash for ClearedFlags<F> {
    const READ_SIZE: usize = F::READ_SIZE;

    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Self::Error> {
        self.0.read(offset, bytes)
    }

    fn capacity(&self) -> usize {
        self.0.capacity()
    }
}

impl<F: NorFlash + StickyErrors> NorFlash for ClearedFlags<F> {
    const WRITE_SIZE: usize = F::WRITE_SIZE;
    const ERASE_SIZE: usize = F::ERASE_SIZE;

    fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
        self.0.clear_errors();
        self.0.erase(from, to)
    }

    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Self::Error> {
        self.0.clear_errors();
        self.0.write(offset, bytes)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use embedded_storage::nor_flash::{ErrorType, NorFlashErrorKind, ReadNorFlash};
    use std::vec::Vec;

    const ERASE: usize = 1024;
    const WRITE: usize = 4;

    /// A NOR flash in RAM with the rules of real NOR: reads and writes aligned, a write only on
    /// erased bytes, erases whole aligned blocks; erases counted per block. `cut` plays a power
    /// loss: after that many more bytes are programmed (or at an erase when 0), the operation
    /// stops half done and every later one fails, until [`RamFlash::power_cycle`].
    #[derive(Debug, Clone)]
    struct RamFlash {
        mem: Vec<u8>,
        erases: Vec<u32>,
        cut: Option<usize>,
        dead: bool,
        /// Writes report success but program nothing (a write the driver did not see fail).
        deaf: bool,
    }

    #[derive(Debug, Clone, Copy, PartialEq, Eq)]
    enum FlashError {
        NotAligned,
        OutOfBounds,
        NotErased,
        PowerLost,
    }

    impl embedded_storage::nor_flash::NorFlashError for FlashError {
        fn kind(&self) -> NorFlashErrorKind {
            match self {
                FlashError::NotAligned => NorFlashErrorKind::NotAligned,
                FlashError::OutOfBounds => NorFlashErrorKind::OutOfBounds,
                _ => NorFlashErrorKind::Other,
            }
        }
    }

    impl RamFlash {
        fn new(size: usize) -> Self {
            RamFlash {
                mem: std::vec![0xFF; size],
                erases: std::vec![0; size / ERASE],
                cut: None,
                dead: false,
                deaf: false,
            }
        }
        /// Power back on: the memory as the loss left it.
        fn power_cycle(&mut self) {
            self.cut = None;
            self.dead = false;
        }
        fn check(&self, offset: u32, len: usize, align: usize) -> Result<(), FlashError> {
            if self.dead {
                return Err(FlashError::PowerLost);
            }
            if !(offset as usize).is_multiple_of(align) || !len.is_multiple_of(align) {
                return Err(FlashError::NotAligned);
            }
            if offset as usize + len > self.mem.len() {
                return Err(FlashError::OutOfBounds);
            }
            Ok(())
        }
    }

    impl ErrorType for RamFlash {
        type Error = FlashError;
    }

    impl ReadNorFlash for RamFlash {
        const READ_SIZE: usize = 1;
        fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), FlashError> {
            self.check(offset, bytes.len(), 1)?;
            let o = offset as usize;
            bytes.copy_from_slice(&self.mem[o..o + bytes.len()]);
            Ok(())
        }
        fn capacity(&self) -> usize {
            self.mem.len()
        }
    }

    impl NorFlash for RamFlash {
        const WRITE_SIZE: usize = WRITE;
        const ERASE_SIZE: usize = ERASE;
        fn erase(&mut self, from: u32, to: u32) -> Result<(), FlashError> {
            self.check(from, (to - from) as usize, ERASE)?;
            for b in from as usize / ERASE..to as usize / ERASE {
                self.erases[b] += 1;
                if self.cut == Some(0) {
                    // Half erased: the first half is 0xFF, the rest as it was.
                    self.mem[b * ERASE..b * ERASE + ERASE / 2].fill(0xFF);
                    self.dead = true;
                    return Err(FlashError::PowerLost);
                }
                self.mem[b * ERASE..(b + 1) * ERASE].fill(0xFF);
            }
            Ok(())
        }
        fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), FlashError> {
            self.check(offset, bytes.len(), WRITE)?;
            let o = offset as usize;
            if self.mem[o..o + bytes.len()].iter().any(|&b| b != 0xFF) {
                return Err(FlashError::NotErased);
            }
            if self.deaf {
                return Ok(());
            }
            for (i, &b) in bytes.iter().enumerate() {
                if let Some(c) = self.cut.as_mut() {
                    if *c == 0 {
                        self.dead = true;
                        return Err(FlashError::PowerLost);
                    }
                    *c -= 1;
                }
                self.mem[o + i] = b;
            }
            Ok(())
        }
    }

    const BLOCK: u32 = 2 * ERASE as u32; // 8 slots a block
    const BASE: u32 = ERASE as u32; // not at 0, to catch offset mistakes

    fn cal(k: u32) -> Calibration {
        let mut c = Calibration::DEFAULT;
        c.l1_mm += 1e-3 * f64::from(k);
        c.axes_skew_rad = 1e-6 * f64::from(k);
        c.enc2.zero_count = i64::from(k) - 3;
        c
    }

    fn reopen(flash: RamFlash) -> CalStore<RamFlash> {
        CalStore::open(flash, BASE, BLOCK).unwrap()
    }

    #[test]
    fn empty_flash_has_nothing_and_a_stored_value_survives_power_cycles() {
        let s = reopen(RamFlash::new(8 * ERASE));
        assert_eq!(s.load(), None);
        let mut s = s;
        s.store(&cal(1)).unwrap();
        assert_eq!(s.load(), Some(cal(1)));
        let s = reopen(s.into_inner());
        assert_eq!(s.load(), Some(cal(1)));
        // Outside the region nothing was touched.
        let f = s.into_inner();
        assert!(f.mem[..BASE as usize].iter().all(|&b| b == 0xFF));
        assert!(f.mem[(BASE + 2 * BLOCK) as usize..]
            .iter()
            .all(|&b| b == 0xFF));
    }

    #[test]
    fn many_stores_alternate_blocks_and_wear_evenly() {
        let mut flash = RamFlash::new(8 * ERASE);
        let n = 1000u32;
        for k in 0..n {
            // A power cycle between stores: re-open from the same memory.
            let mut s = reopen(flash);
            s.store(&cal(k)).unwrap();
            flash = s.into_inner();
            assert_eq!(reopen(flash.clone()).load(), Some(cal(k)), "store {k}");
        }
        let slots_per_block = BLOCK / SLOT as u32;
        // One erase per full block: about n / slots_per_block erases over the region's 4 erase
        // pages, spread evenly, and none outside it.
        let total: u32 = flash.erases.iter().sum();
        // Both blocks start erased: the first switch (into block 1) needs no erase.
        let switches = (n - 1) / slots_per_block;
        assert_eq!(
            total,
            (switches - 1) * (BLOCK / ERASE as u32),
            "{:?}",
            flash.erases
        );
        let region = &flash.erases[1..5];
        let (lo, hi) = (region.iter().min().unwrap(), region.iter().max().unwrap());
        assert!(hi - lo <= 1, "uneven wear {region:?}");
        assert_eq!(flash.erases[0] + flash.erases[5..].iter().sum::<u32>(), 0);
    }

    #[test]
    fn the_spare_erased_ahead_keeps_every_erase_out_of_the_stores() {
        // As the firmware does: erase ahead at every power-up and whenever it stops sampling
        // (here: after every 3rd store); then no store ever erases, over several block switches.
        let slots = BLOCK / SLOT as u32;
        let mut s = reopen(RamFlash::new(8 * ERASE));
        assert!(!s.erase_spare().unwrap(), "a blank flash needs no erase");
        let mut erases_in_stores = 0;
        for k in 0..5 * slots {
            if k % 3 == 0 {
                let before: u32 = s.flash.erases.iter().sum();
                let erased = s.erase_spare().unwrap();
                let after: u32 = s.flash.erases.iter().sum();
                assert_eq!(erased, after > before, "store {k}");
            }
            assert!(!s.store_would_erase().unwrap(), "store {k}");
            let before: u32 = s.flash.erases.iter().sum();
            s.store(&cal(k)).unwrap();
            erases_in_stores += s.flash.erases.iter().sum::<u32>() - before;
            assert_eq!(s.load(), Some(cal(k)));
        }
        assert_eq!(erases_in_stores, 0);
        // Re-opened, the store knows again whether the spare is erased.
        let mut s = reopen(s.into_inner());
        assert_eq!(s.load(), Some(cal(5 * slots - 1)));
        s.erase_spare().unwrap();
        let mut s = reopen(s.into_inner());
        assert!(!s.erase_spare().unwrap(), "erased before the power cycle");

        // Without erasing ahead, the store that switches blocks says beforehand that it erases,
        // and does.
        let mut s = reopen(RamFlash::new(8 * ERASE));
        for k in 0..2 * slots {
            assert!(
                !s.store_would_erase().unwrap(),
                "store {k}: both blocks start blank"
            );
            s.store(&cal(k)).unwrap();
        }
        assert!(s.store_would_erase().unwrap());
        let before: u32 = s.flash.erases.iter().sum();
        s.store(&cal(99)).unwrap();
        assert_eq!(
            s.flash.erases.iter().sum::<u32>() - before,
            BLOCK / ERASE as u32
        );
        assert_eq!(reopen(s.into_inner()).load(), Some(cal(99)));
    }

    #[test]
    fn a_write_or_erase_cut_by_a_power_loss_leaves_the_old_value() {
        // Cut every store at every byte of its write, and at its erase, from every fill level.
        let slots = BLOCK / SLOT as u32;
        for before in 1..=2 * slots + 1 {
            let mut base = reopen(RamFlash::new(8 * ERASE));
            for k in 0..before {
                base.store(&cal(k)).unwrap();
            }
            let flash = base.into_inner();
            let old = cal(before - 1);
            for cut in [0usize, 1, 3, 4, 5, 11, 12, 100, SLOT - 5, SLOT - 1] {
                let mut f = flash.clone();
                f.cut = Some(cut);
                let mut s = reopen(f);
                let r = s.store(&cal(999));
                let mut f = s.into_inner();
                f.power_cycle();
                let got = reopen(f.clone()).load();
                if r.is_ok() {
                    // The cut fell beyond what this store programs.
                    assert!(cut >= 100, "before {before}, cut {cut}");
                    assert_eq!(got, Some(cal(999)), "before {before}, cut {cut}");
                } else {
                    assert_eq!(got, Some(old), "before {before}, cut {cut}");
                }
                // And the store works again after the power cycle, over the torn slot.
                let mut s = reopen(f);
                s.store(&cal(1000)).unwrap();
                assert_eq!(reopen(s.into_inner()).load(), Some(cal(1000)));
            }
        }
    }

    #[test]
    fn other_versions_corruption_and_bad_geometry_are_refused() {
        let mut s = reopen(RamFlash::new(8 * ERASE));
        s.store(&cal(1)).unwrap();
        s.store(&cal(2)).unwrap();
        let mut f = s.into_inner();
        // Corrupt the newest record's payload: the one before it is the newest valid.
        f.mem[BASE as usize + SLOT + 20] ^= 0x01;
        assert_eq!(reopen(f.clone()).load(), Some(cal(1)));
        // Another format version: ignored.
        f.mem[BASE as usize + 4] = FORMAT_VERSION + 1;
        assert_eq!(reopen(f.clone()).load(), None);
        // Regions that do not fit the flash.
        for (base, block) in [
            (0, 100),
            (0, 512),
            (1, 2048),
            (4 * ERASE as u32, 4096),
            (0, 0),
        ] {
            assert!(matches!(
                CalStore::open(f.clone(), base, block),
                Err(StoreError::Geometry)
            ));
        }
    }

    #[test]
    fn a_write_that_does_not_take_is_not_reported_stored() {
        // Issue 32 §1: the store reads its record back; a write that reported success but left
        // the flash unchanged is `ReadBack`, and the calibration stored before stays the newest.
        let mut s = reopen(RamFlash::new(8 * ERASE));
        s.store(&cal(1)).unwrap();
        s.flash.deaf = true;
        let r = s.store(&cal(2));
        assert_eq!(r, Err(StoreError::ReadBack));
        assert_eq!(kept(&r), CalKept::ReadBackDiffers);
        assert_eq!(s.load(), Some(cal(1)));
        let mut f = s.into_inner();
        f.deaf = false;
        assert_eq!(reopen(f.clone()).load(), Some(cal(1)));
        // A flash that fails outright is the flash's own error.
        f.dead = true;
        let mut s = CalStore {
            flash: f,
            base: BASE,
            block: BLOCK,
            newest: None,
            spare_erased: true,
        };
        let r = s.store(&cal(3));
        assert_eq!(r, Err(StoreError::Flash(FlashError::PowerLost)));
        assert_eq!(kept(&r), CalKept::WriteFailed);
        s.spare_erased = false;
        let r = s.erase_spare().map(|_| ());
        assert_eq!(r, Err(StoreError::Erase(FlashError::PowerLost)));
        assert_eq!(kept(&r), CalKept::EraseFailed);
        assert_eq!(kept::<FlashError>(&Ok(())), CalKept::Stored);
        // Working again, the next store lands in a fresh slot.
        s.flash.dead = false;
        let mut s = reopen(s.into_inner());
        s.store(&cal(4)).unwrap();
        assert_eq!(reopen(s.into_inner()).load(), Some(cal(4)));
    }

    #[test]
    fn the_largest_calibration_fits_a_slot() {
        let mut c = Calibration::DEFAULT;
        c.enc1.counts_per_rev = u32::MAX;
        c.enc1.zero_count = i64::MIN;
        c.enc2.zero_count = i64::MAX;
        let mut buf = [0u8; SLOT];
        let n = postcard::to_slice(&c, &mut buf).unwrap().len();
        assert!(HEADER + n + 4 <= SLOT, "{n}");
    }

    /// The F4's flash controller over [`RamFlash`]: an error flag, set by a failing operation
    /// (`fail`: the next program fails, as on a protected sector, programming nothing) and
    /// failing every operation while set, as the HAL checks it.
    struct FlagFlash {
        ram: RamFlash,
        flag: bool,
        fail: bool,
    }
    impl ErrorType for FlagFlash {
        type Error = FlashError;
    }
    impl ReadNorFlash for FlagFlash {
        const READ_SIZE: usize = 1;
        fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), FlashError> {
            self.ram.read(offset, bytes)
        }
        fn capacity(&self) -> usize {
            self.ram.capacity()
        }
    }
    impl NorFlash for FlagFlash {
        const WRITE_SIZE: usize = WRITE;
        const ERASE_SIZE: usize = ERASE;
        fn erase(&mut self, from: u32, to: u32) -> Result<(), FlashError> {
            self.ram.erase(from, to)?;
            if self.flag {
                return Err(FlashError::PowerLost);
            }
            Ok(())
        }
        fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), FlashError> {
            if self.fail {
                self.flag = true;
            } else {
                self.ram.write(offset, bytes)?;
            }
            if self.flag {
                return Err(FlashError::PowerLost);
            }
            Ok(())
        }
    }
    impl StickyErrors for FlagFlash {
        fn clear_errors(&mut self) {
            self.flag = false;
        }
    }

    #[test]
    fn a_store_that_fails_leaves_its_flag_and_the_reply_says_so() {
        // Issue 34: the store over the flash seam (NorFlash) with the F4's sticky error flags.
        // A flag left set before the firmware started (a DFU `:leave`) does not fail a store.
        let flash = FlagFlash {
            ram: RamFlash::new(8 * ERASE),
            flag: true,
            fail: false,
        };
        let mut s = CalStore::open(ClearedFlags(flash), BASE, BLOCK).unwrap();
        let r = s.store(&cal(1));
        assert_eq!(kept(&r), CalKept::Stored, "{r:?}");
        // A program that fails sets its flag, which stays set: the reply says the store failed
        // (never `Stored`), and the calibration stored before is still the newest.
        s.flash.0.fail = true;
        let r = s.store(&cal(2));
        assert_eq!(r, Err(StoreError::Flash(FlashError::PowerLost)));
        assert_eq!(kept(&r), CalKept::WriteFailed);
        assert!(s.flash.0.flag, "the error flag is left set");
        assert_eq!(s.load(), Some(cal(1)));
        // The flash working again, the flag the failure left does not fail the next store.
        s.flash.0.fail = false;
        assert_eq!(kept(&s.store(&cal(3))), CalKept::Stored);
        let ram = s.into_inner().0.ram;
        assert_eq!(reopen(ram).load(), Some(cal(3)));
    }
}
