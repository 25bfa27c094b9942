//! The wire protocol: every message between the J-DBB and the host, defined once and imported by
//! both sides (like postcard-rpc's ICD crate).
//!
//! # Frame layout
//!
//! ```text
//!   COBS( postcard(message) ‖ CRC-32C(postcard(message)) as 4 bytes little-endian ) ‖ 0x00
//! ```
//!
//! - `postcard(message)`: the [`DeviceMsg`] or [`Command`] enum in postcard's format — the variant
//!   index as a varint, then its fields in order; integers as varints (signed ones zig-zag),
//!   `f64` as 8 bytes little-endian, `heapless::Vec` as a varint length then its elements.
//! - CRC-32C (Castagnoli, `crc::CRC_32_ISCSI`) over the postcard bytes, appended little-endian.
//! - COBS removes every 0x00 from payload + CRC; a single 0x00 ends each frame, so a receiver that
//!   joins mid-stream or meets garbage resynchronises at the next 0x00.
//!
//! The format is a contract: `tests` at the bottom pin exact bytes (golden vectors). Any change to a
//! message must bump [`PROTOCOL_VERSION`], which the device reports in [`DeviceInfo`].
//!
//! # Versions
//!
//! - **1**: the first release.
//! - **2**: [`DeviceInfo`] ends with the device's health and identity — [`DeviceInfo::chip_id`]
//!   (the chip's unique ID, also the USB serial number), [`DeviceInfo::reset_cause`] (why the
//!   device last started, including a recorded panic or fault), [`DeviceInfo::index`] (index
//!   referencing of both encoders, [`IndexStatus`]) and [`DeviceInfo::overruns`] (sample-clock
//!   ticks the sample task missed, also counted as dropped); [`Command::ArmIndex`] is new (it
//!   is the last variant, so the indices of the version-1 commands are unchanged). The
//!   [`Calibration`] in `Info` and `SetCalibration` carries the extended instrument model (per
//!   encoder a fine zero and the once-per-turn error; skew, tilts and pivot offsets of the
//!   frames). New fields are appended at the end of a struct and new variants at the end of an
//!   enum.
//! - **3**: [`DeviceInfo::clock`] ([`ClockSource`]) ends the description: whether the device's
//!   clocks, and so every `t_us`, run from the crystal or, because it did not start, from the
//!   chip's internal oscillator (±1 %).
//! - **4**: [`DeviceInfo::calibration_kept`] ([`CalKept`]): what became of the last calibration
//!   the host sent — kept in flash and read back equal, or why not (issue 32: a failed store was
//!   only logged over the debug probe, and the host reported success); then
//!   [`DeviceInfo::unhandled_irq`]: the interrupt without a handler that made the firmware reset
//!   itself (reported before as a watchdog reset, after the stray interrupt spun until it bit);
//!   then [`DeviceInfo::index_disabled`]: an index input switched off for interrupting too fast.

use crc::{Crc, CRC_32_ISCSI};
use serde::{de::DeserializeOwned, Deserialize, Serialize};

use crate::calib::{Calibration, CalibrationError};

/// Version of this wire format. Bump on any change to a message or the framing.
/// See the module docs' *Versions*.
pub const PROTOCOL_VERSION: u16 = 4;

/// Samples per [`SampleBatch`].
pub const BATCH_LEN: usize = 16;

/// Largest encoded frame (bytes, including COBS overhead and the 0x00 delimiter) any message can
/// produce; buffers of this size never overflow. Checked against worst-case messages in tests.
pub const MAX_FRAME_LEN: usize = 704;

/// Largest sample rate the firmware accepts (Hz).
pub const MAX_SAMPLE_RATE_HZ: u32 = 20_000;

/// Largest sample rate the board is known to sustain end to end (Hz): the host refuses a rate
/// above it (README, "Throughput budget"). A sample costs ~1 824 instructions on the chip
/// (`scripts/fw-cycles.sh`: sample path and frame encoding; 23–29 µs at 96 MHz) and 23 bytes on
/// the link (`tests::throughput_budget`: 365 bytes per 16-sample frame): at 10 kHz 23–29 % of
/// the CPU, 228 kB/s, ~3 600 full-speed USB packets/s; at 20 kHz 46–57 % of the CPU before the
/// USB interrupts, 456 kB/s, ~7 100 packets/s with one packet in flight — not shown on a board,
/// and overruns are likely there.
pub const SUSTAINED_SAMPLE_RATE_HZ: u32 = 10_000;

const CRC32C: Crc<u32> = Crc::<u32>::new(&CRC_32_ISCSI);

/// Status bits of one sample.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Status(pub u8);

impl Status {
    /// Encoder 1 is referenced (index seen, or zeroed by command).
    pub const ENC1_REFERENCED: u8 = 1 << 0;
    /// Encoder 2 is referenced.
    pub const ENC2_REFERENCED: u8 = 1 << 1;
    /// A frame angle is outside the mechanical working range: D is not trustworthy.
    pub const OUT_OF_RANGE: u8 = 1 << 2;
    /// Counts come from the simulated encoders of the QEMU build, not from hardware.
    pub const SIMULATED: u8 = 1 << 3;

    /// Whether all bits of `mask` are set.
    pub fn has(self, mask: u8) -> bool {
        self.0 & mask == mask
    }
}

/// One sample: what the instrument read at one tick of its sample clock.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Sample {
    /// Time of the sample since the device started sampling (µs).
    pub t_us: u64,
    /// Extended count of encoder 1 (frame about x).
    pub enc1: i64,
    /// Extended count of encoder 2 (frame about y).
    pub enc2: i64,
    /// Ball distance D computed on the device (mm).
    pub d_mm: f64,
    /// Status bits, see [`Status`].
    pub status: Status,
}

/// A batch of consecutive samples. Sample `i` has sequence number `seq + i`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SampleBatch {
    /// Sequence number of the first sample; counts every sample taken since sampling started,
    /// including dropped ones, so a gap in `seq` equals the samples dropped in between.
    pub seq: u32,
    /// Total samples the device dropped since sampling started: queue or link full, no host
    /// reading, or sample-clock overruns ([`DeviceInfo::overruns`]).
    pub dropped: u32,
    /// The samples, oldest first.
    pub samples: heapless::Vec<Sample, BATCH_LEN>,
}

/// Which hardware the firmware runs on.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Board {
    /// STM32F411CEU6 "Black Pill", encoders on TIM2/TIM5, USB FS CDC-ACM.
    BlackPillF411,
    /// QEMU `netduinoplus2`: simulated encoders, USART2.
    QemuNetduinoPlus2,
}

/// How an encoder's count zero is defined.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Reference {
    /// Not referenced: counts are relative to power-up.
    None,
    /// Count zero is the index window's lower edge (see `quadrature::Encoder`).
    Index,
    /// Count zero is where the host sent [`Command::Zero`].
    Zero,
}

/// Index referencing of one encoder, as reported in [`DeviceInfo::index`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct IndexStatus {
    /// What count zero is.
    pub reference: Reference,
    /// The next accepted index pass will (re-)reference the encoder (at power-up, and after
    /// [`Command::ArmIndex`]).
    pub armed: bool,
    /// Accepted index passes since power-up (the window's lower edge crossed while moving).
    pub passes: u32,
    /// Count, in the reference in force before it, at which the last accepted pass was seen:
    /// 0 (±1 count) while no count is lost or gained; after a re-reference, how far the zero moved.
    pub last_pass_count: i64,
}

/// Why the device last started: reset flags of the chip plus what the firmware recorded before a
/// reset it caused itself. Several bits can be set (a power-on also sets the pin-reset flag).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ResetCause(pub u8);

impl ResetCause {
    /// The NRST pin was pulled low (reset button, a debug probe, and every power-on).
    pub const PIN: u8 = 1 << 0;
    /// Power-on or power-down reset.
    pub const POWER: u8 = 1 << 1;
    /// Supply brown-out.
    pub const BROWN_OUT: u8 = 1 << 2;
    /// Software reset (`SYSRESETREQ`): the firmware reset itself, see [`Self::PANIC`] and
    /// [`Self::FAULT`], or a debug probe did.
    pub const SOFTWARE: u8 = 1 << 3;
    /// Independent or window watchdog.
    pub const WATCHDOG: u8 = 1 << 4;
    /// Low-power management reset.
    pub const LOW_POWER: u8 = 1 << 5;
    /// The firmware panicked and reset itself.
    pub const PANIC: u8 = 1 << 6;
    /// A hard fault (bus, memory or usage fault escalated) made the firmware reset itself.
    pub const FAULT: u8 = 1 << 7;

    /// Whether all bits of `mask` are set.
    pub fn has(self, mask: u8) -> bool {
        self.0 & mask == mask
    }

    /// Whether the firmware reset itself after a panic or a fault.
    pub fn crashed(self) -> bool {
        self.0 & (Self::PANIC | Self::FAULT) != 0
    }
}

/// What the device's clocks run from, and so how good every `t_us` and the sample rate are. (v3)
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ClockSource {
    /// The board's crystal, through the PLL: time as good as the crystal (tens of ppm).
    Crystal,
    /// The crystal did not start, or is another supported crystal than the one the firmware was
    /// built for: the chip's internal RC oscillator (the STM32F411's HSI, ±1 % at 25 °C, ±4 %
    /// over −10…85 °C, DS10314). Time stamps and the sample rate are off by up to 4 % (of D's
    /// time axis, not of D), and USB, which needs ±0.25 %, does not run on it: the device is
    /// reached over USB only if the HSI happens to be within that, so this is mostly seen in the
    /// debug log and on the LED (two flashes).
    Internal,
    /// QEMU's virtual clock (the QEMU build).
    Emulated,
}

/// What became of the last calibration the host sent ([`Command::SetCalibration`]), in the
/// device's non-volatile store. Whatever it says, the calibration sent is in force until the
/// next power cycle; only [`CalKept::Stored`] means it is still in force after one. (v4)
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum CalKept {
    /// No calibration was sent since the device started.
    NotSent,
    /// Written to flash and read back equal: it survives a power cycle.
    Stored,
    /// Not kept: the device has no room for the store (an STM32F411xC, 256 KiB, has no sectors
    /// 6 and 7).
    NoRoom,
    /// Not kept: erasing the store's spare flash sector failed (the flash reported an error).
    EraseFailed,
    /// Not kept: programming the record failed (the flash's status flags reported an error:
    /// write protection, a programming sequence, alignment or parallelism error).
    WriteFailed,
    /// Not kept: the record was written without an error, but the flash read back differs.
    ReadBackDiffers,
}

/// The device's description of itself: sent at start-up and in reply to [`Command::GetInfo`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct DeviceInfo {
    /// [`PROTOCOL_VERSION`] of the firmware.
    pub protocol_version: u16,
    /// Firmware version (major, minor, patch).
    pub firmware_version: [u8; 3],
    /// Hardware.
    pub board: Board,
    /// Sample clock (Hz).
    pub sample_rate_hz: u32,
    /// Whether the device is streaming samples.
    pub sampling: bool,
    /// The calibration in force: D in every sample was computed with it.
    pub calibration: Calibration,
    /// The chip's 96-bit unique ID, as it lies in memory; all zero on QEMU. Its 24 upper-case
    /// hex digits, in this order, are the board's USB serial number. (v2)
    pub chip_id: [u8; 12],
    /// Why the device last started. (v2)
    pub reset_cause: ResetCause,
    /// Index referencing of encoders 1 and 2. (v2)
    pub index: [IndexStatus; 2],
    /// Sample-clock ticks the sample task missed since sampling started (it ran more than one
    /// period late); each is also counted in [`SampleBatch::dropped`]. (v2)
    pub overruns: u32,
    /// What the clocks run from: the accuracy of the time stamps. (v3)
    pub clock: ClockSource,
    /// What became of the last calibration sent: kept in flash (read back equal), or why not.
    /// In the reply to [`Command::SetCalibration`] it is that command's store. (v4)
    pub calibration_kept: CalKept,
    /// With [`ResetCause::FAULT`]: the interrupt that had no handler and made the firmware reset
    /// itself, as its IRQ number (negative for a core exception, as CMSIS numbers them); `None`
    /// for any other start. (v4)
    pub unhandled_irq: Option<i16>,
    /// Per encoder: its index input was switched off because it interrupted faster than an
    /// index can (a mis-wired or noisy line, `quadrature::IndexRateLimit`); it stays off until
    /// the next power-up. (v4)
    pub index_disabled: [bool; 2],
}

/// The device's greeting: who it is and why it started — [`DeviceInfo`] without the calibration,
/// the index status and the overrun count, so that its frame fits one 64-byte full-speed USB
/// packet (a host that opens the port after the device was configured still receives it whole,
/// from the endpoint's buffer). Sent at power-up on the UART and when a USB host configures the
/// device; the full description is [`DeviceMsg::Info`], in reply to [`Command::GetInfo`]. (v2)
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Hello {
    /// [`PROTOCOL_VERSION`] of the firmware.
    pub protocol_version: u16,
    /// Firmware version (major, minor, patch).
    pub firmware_version: [u8; 3],
    /// Hardware.
    pub board: Board,
    /// Sample clock (Hz).
    pub sample_rate_hz: u32,
    /// Whether the device is streaming samples.
    pub sampling: bool,
    /// As [`DeviceInfo::chip_id`].
    pub chip_id: [u8; 12],
    /// As [`DeviceInfo::reset_cause`].
    pub reset_cause: ResetCause,
}

impl Hello {
    /// The greeting part of a full description.
    pub fn of(info: &DeviceInfo) -> Hello {
        Hello {
            protocol_version: info.protocol_version,
            firmware_version: info.firmware_version,
            board: info.board,
            sample_rate_hz: info.sample_rate_hz,
            sampling: info.sampling,
            chip_id: info.chip_id,
            reset_cause: info.reset_cause,
        }
    }
}

/// Device → host.
// The batch is by far the largest variant on purpose: it is the message that is sent 1000s of times
// per second, and no_std code cannot box it.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub enum DeviceMsg {
    /// Description of the device (start-up, or reply to [`Command::GetInfo`] and to accepted
    /// configuration commands).
    Info(DeviceInfo),
    /// Samples.
    Batch(SampleBatch),
    /// Reply to [`Command::Ping`] with the same token.
    Pong(u32),
    /// A command was refused.
    Rejected(CommandError),
    /// The device's greeting (see [`Hello`]). (v2)
    Hello(Hello),
}

/// Host → device.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Command {
    /// Start sampling; sequence numbers and time restart at 0.
    Start,
    /// Stop sampling.
    Stop,
    /// Set the sample clock (Hz, 1 ..= [`MAX_SAMPLE_RATE_HZ`]).
    SetSampleRate(u32),
    /// Replace the calibration in force.
    SetCalibration(Calibration),
    /// Make the current position of both encoders count zero.
    Zero,
    /// Liveness check; answered with [`DeviceMsg::Pong`].
    Ping(u32),
    /// Ask for [`DeviceMsg::Info`].
    GetInfo,
    /// Re-arm the index of both encoders: the next accepted pass over each index re-references
    /// that encoder (the reference in force stays until then). Answered with
    /// [`DeviceMsg::Info`]. (v2)
    ArmIndex,
}

/// Why the device refused a command.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum CommandError {
    /// Sample rate outside 1 ..= [`MAX_SAMPLE_RATE_HZ`].
    SampleRateOutOfRange,
    /// The calibration failed validation.
    BadCalibration(CalibrationError),
    /// The command frame could not be decoded.
    Malformed,
}

/// Why encoding or decoding a frame failed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum FrameError {
    /// The output buffer is too small for the message.
    BufferFull,
    /// More bytes than [`MAX_FRAME_LEN`] arrived without a 0x00 delimiter.
    Overflow,
    /// The bytes between two delimiters are not valid COBS.
    Cobs,
    /// The frame is shorter than its CRC, or the CRC does not match.
    Crc,
    /// Valid CRC but the payload is not a known message (e.g. a protocol version mismatch).
    Payload,
}

impl core::fmt::Display for FrameError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            FrameError::BufferFull => "output buffer too small",
            FrameError::Overflow => "frame longer than the maximum",
            FrameError::Cobs => "invalid COBS encoding",
            FrameError::Crc => "CRC mismatch",
            FrameError::Payload => "unknown message",
        })
    }
}

/// Encode one message into `buf` as a complete frame (see the module docs); returns the used part,
/// ending with the 0x00 delimiter.
pub fn encode<'a, T: Serialize>(msg: &T, buf: &'a mut [u8]) -> Result<&'a mut [u8], FrameError> {
    use postcard::ser_flavors::{crc::CrcModifier, Cobs, Slice};
    let flavor = CrcModifier::new(
        Cobs::try_new(Slice::new(buf)).map_err(|_| FrameError::BufferFull)?,
        CRC32C.digest(),
    );
    postcard::serialize_with_flavor(msg, flavor).map_err(|_| FrameError::BufferFull)
}

/// Decode one frame's bytes (between delimiters, without the 0x00), in place.
pub fn decode_frame<T: DeserializeOwned>(frame: &mut [u8]) -> Result<T, FrameError> {
    let n = cobs::decode_in_place(frame).map_err(|_| FrameError::Cobs)?;
    if n < 4 {
        return Err(FrameError::Crc);
    }
    // Check the CRC before interpreting any payload byte, so a corrupted frame is always reported
    // as corrupted, never as an unknown message.
    let (payload, crc) = frame[..n].split_at(n - 4);
    if CRC32C.checksum(payload).to_le_bytes() != crc {
        return Err(FrameError::Crc);
    }
    postcard::from_bytes(payload).map_err(|_| FrameError::Payload)
}

/// Splits a byte stream into frames and decodes them, resynchronising after garbage: bytes are
/// collected up to each 0x00; an over-long run is discarded whole and reported once as
/// [`FrameError::Overflow`]. Fixed memory, no allocation — used by both the host and the firmware.
pub struct Decoder<const N: usize = MAX_FRAME_LEN> {
    buf: [u8; N],
    len: usize,
    overflowed: bool,
}

impl<const N: usize> Default for Decoder<N> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const N: usize> Decoder<N> {
    /// An empty decoder.
    pub const fn new() -> Self {
        Decoder {
            buf: [0; N],
            len: 0,
            overflowed: false,
        }
    }

    /// Feed received bytes; `on_frame` is called once per complete frame, in order, with the
    /// decoded message or the reason it was rejected.
    pub fn feed<T: DeserializeOwned>(
        &mut self,
        bytes: &[u8],
        mut on_frame: impl FnMut(Result<T, FrameError>),
    ) {
        let mut rest = bytes;
        while !rest.is_empty() {
            match rest.iter().position(|&b| b == 0) {
                Some(end) => {
                    self.push_bytes(&rest[..end]);
                    if self.overflowed {
                        on_frame(Err(FrameError::Overflow));
                    } else if self.len > 0 {
                        on_frame(decode_frame(&mut self.buf[..self.len]));
                    }
                    self.len = 0;
                    self.overflowed = false;
                    rest = &rest[end + 1..];
                }
                None => {
                    self.push_bytes(rest);
                    rest = &[];
                }
            }
        }
    }

    fn push_bytes(&mut self, bytes: &[u8]) {
        if self.overflowed {
            return;
        }
        if self.len + bytes.len() > N {
            self.overflowed = true;
            self.len = 0;
            return;
        }
        self.buf[self.len..self.len + bytes.len()].copy_from_slice(bytes);
        self.len += bytes.len();
    }

    /// Bytes held of an unfinished frame.
    pub fn pending(&self) -> usize {
        self.len
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calib::{Direction, EncoderCal, FrameCal};
    use proptest::prelude::*;

    fn golden_batch() -> DeviceMsg {
        let mut samples = heapless::Vec::new();
        samples
            .push(Sample {
                t_us: 1000,
                enc1: -3,
                enc2: 20_000,
                d_mm: 90.0,
                status: Status(Status::ENC1_REFERENCED | Status::SIMULATED),
            })
            .unwrap();
        samples
            .push(Sample {
                t_us: 2000,
                enc1: 1,
                enc2: -1,
                d_mm: 100.0,
                status: Status(0),
            })
            .unwrap();
        DeviceMsg::Batch(SampleBatch {
            seq: 300,
            dropped: 2,
            samples,
        })
    }

    fn golden_info() -> DeviceMsg {
        DeviceMsg::Info(DeviceInfo {
            protocol_version: PROTOCOL_VERSION,
            firmware_version: [0, 1, 0],
            board: Board::QemuNetduinoPlus2,
            sample_rate_hz: 1000,
            sampling: true,
            calibration: Calibration::DEFAULT,
            chip_id: [
                0x30, 0x00, 0x2d, 0x00, 0x10, 0x51, 0x33, 0x39, 0x38, 0x31, 0x35, 0x32,
            ],
            reset_cause: ResetCause(ResetCause::SOFTWARE | ResetCause::PANIC | ResetCause::PIN),
            index: [
                IndexStatus {
                    reference: Reference::Index,
                    armed: false,
                    passes: 3,
                    last_pass_count: -1,
                },
                IndexStatus {
                    reference: Reference::None,
                    armed: true,
                    passes: 0,
                    last_pass_count: 0,
                },
            ],
            overruns: 2,
            clock: ClockSource::Internal,
            calibration_kept: CalKept::ReadBackDiffers,
            unhandled_irq: Some(-3),
            index_disabled: [false, true],
        })
    }

    fn enc_vec<T: Serialize>(m: &T) -> std::vec::Vec<u8> {
        let mut buf = [0u8; MAX_FRAME_LEN];
        encode(m, &mut buf).unwrap().to_vec()
    }

    fn decode_all<T: DeserializeOwned>(bytes: &[u8]) -> std::vec::Vec<Result<T, FrameError>> {
        let mut d = Decoder::<MAX_FRAME_LEN>::new();
        let mut out = std::vec::Vec::new();
        d.feed(bytes, |r| out.push(r));
        out
    }

    // Golden vectors: the exact bytes on the wire. If one of these fails, the format changed:
    // bump PROTOCOL_VERSION and update the host and firmware together.
    #[test]
    fn golden_sample_batch() {
        let bytes = enc_vec(&golden_batch());
        assert_eq!(bytes, GOLDEN_BATCH, "got {bytes:02x?}");
    }

    #[test]
    fn golden_device_info() {
        let bytes = enc_vec(&golden_info());
        assert_eq!(bytes, GOLDEN_INFO, "got {bytes:02x?}");
    }

    #[test]
    fn golden_hello() {
        let DeviceMsg::Info(info) = golden_info() else {
            unreachable!()
        };
        let hello = DeviceMsg::Hello(Hello::of(&info));
        let bytes = enc_vec(&hello);
        assert_eq!(bytes, GOLDEN_HELLO, "got {bytes:02x?}");
        assert!(bytes.len() <= 64);
        assert_eq!(decode_all::<DeviceMsg>(GOLDEN_HELLO), std::vec![Ok(hello)]);
    }

    /// A calibration with every field distinct, in exactly representable values (powers of two), so
    /// the golden bytes show the field order: l1, l2, enc1 {counts/rev, zero count, direction,
    /// zero offset, eccentricity, phase}, enc2 {…}, skew, frame1 {tilt, offset normal, offset
    /// axial}, frame2 {…}.
    fn golden_calibration() -> Calibration {
        let p = |e: i32| libm::ldexp(1.0, e);
        let mut c = Calibration::nominal(50.0, 49.5, 1 << 23);
        c.enc1.zero_count = -3;
        c.enc1.zero_offset_rad = p(-12);
        c.enc1.eccentricity_rad = p(-13);
        c.enc1.eccentricity_phase_rad = 1.5;
        c.enc2.counts_per_rev = 1 << 20;
        c.enc2.zero_count = 1000;
        c.enc2.direction = Direction::Negative;
        c.enc2.zero_offset_rad = -p(-12);
        c.enc2.eccentricity_rad = p(-14);
        c.enc2.eccentricity_phase_rad = -0.25;
        c.axes_skew_rad = p(-11);
        c.frame1 = FrameCal {
            tilt_rad: -p(-11),
            offset_normal_rad: p(-15),
            offset_axial_rad: -p(-15),
        };
        c.frame2 = FrameCal {
            tilt_rad: p(-10),
            offset_normal_rad: -p(-16),
            offset_axial_rad: p(-16),
        };
        c.validate().unwrap();
        c
    }

    #[test]
    fn golden_commands() {
        let set = enc_vec(&Command::SetCalibration(golden_calibration()));
        assert_eq!(set, GOLDEN_SET_CALIBRATION, "got {set:02x?}");
        assert_eq!(enc_vec(&Command::Start), GOLDEN_START);
        assert_eq!(enc_vec(&Command::SetSampleRate(10_000)), GOLDEN_RATE);
        assert_eq!(enc_vec(&Command::Ping(0xdead_beef)), GOLDEN_PING);
        assert_eq!(enc_vec(&Command::ArmIndex), GOLDEN_ARM_INDEX);
    }

    #[test]
    fn version_1_commands_keep_their_bytes() {
        // v2 only appended `ArmIndex`: a v1 host's commands still decode to the same commands.
        assert_eq!(
            decode_all::<Command>(GOLDEN_START),
            std::vec![Ok(Command::Start)]
        );
        assert_eq!(
            decode_all::<Command>(GOLDEN_PING),
            std::vec![Ok(Command::Ping(0xdead_beef))]
        );
    }

    const GOLDEN_BATCH: &[u8] = &[
        0x0c, 0x01, 0xac, 0x02, 0x02, 0x02, 0xe8, 0x07, 0x05, 0xc0, 0xb8, 0x02, 0x01, 0x01, 0x01,
        0x01, 0x09, 0x80, 0x56, 0x40, 0x09, 0xd0, 0x0f, 0x02, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01,
        0x03, 0x59, 0x40, 0x05, 0x50, 0x2e, 0x61, 0xe0, 0x00,
    ];
    const GOLDEN_INFO: &[u8] = &[
        0x01, 0x02, 0x04, 0x02, 0x01, 0x05, 0x01, 0xe8, 0x07, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01,
        0x03, 0x49, 0x40, 0x01, 0x01, 0x01, 0x01, 0x01, 0x07, 0x49, 0x40, 0x80, 0x80, 0x80, 0x04,
        0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01,
        0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x05, 0x80, 0x80, 0x80, 0x04,
        0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01,
        0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01,
        0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01,
        0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01,
        0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01,
        0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x02, 0x30, 0x02, 0x2d, 0x0b, 0x10, 0x51, 0x33, 0x39,
        0x38, 0x31, 0x35, 0x32, 0x49, 0x01, 0x03, 0x03, 0x01, 0x02, 0x01, 0x01, 0x06, 0x02, 0x01,
        0x05, 0x01, 0x05, 0x06, 0x01, 0x52, 0x16, 0xba, 0x49, 0x00,
    ];
    const GOLDEN_SET_CALIBRATION: &[u8] = &[
        0x02, 0x03, 0x01, 0x01, 0x01, 0x01, 0x01, 0x03, 0x49, 0x40, 0x01, 0x01, 0x01, 0x01, 0x09,
        0xc0, 0x48, 0x40, 0x80, 0x80, 0x80, 0x04, 0x05, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x03,
        0x30, 0x3f, 0x01, 0x01, 0x01, 0x01, 0x01, 0x03, 0x20, 0x3f, 0x01, 0x01, 0x01, 0x01, 0x01,
        0x09, 0xf8, 0x3f, 0x80, 0x80, 0x40, 0xd0, 0x0f, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x03,
        0x30, 0xbf, 0x01, 0x01, 0x01, 0x01, 0x01, 0x03, 0x10, 0x3f, 0x01, 0x01, 0x01, 0x01, 0x01,
        0x03, 0xd0, 0xbf, 0x01, 0x01, 0x01, 0x01, 0x01, 0x03, 0x40, 0x3f, 0x01, 0x01, 0x01, 0x01,
        0x01, 0x03, 0x40, 0xbf, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x02, 0x3f, 0x01, 0x01, 0x01,
        0x01, 0x01, 0x01, 0x02, 0xbf, 0x01, 0x01, 0x01, 0x01, 0x01, 0x03, 0x50, 0x3f, 0x01, 0x01,
        0x01, 0x01, 0x01, 0x03, 0xf0, 0xbe, 0x01, 0x01, 0x01, 0x01, 0x01, 0x07, 0xf0, 0x3e, 0x4f,
        0x12, 0x29, 0x97, 0x00,
    ];
    const GOLDEN_HELLO: &[u8] = &[
        0x03, 0x04, 0x04, 0x02, 0x01, 0x06, 0x01, 0xe8, 0x07, 0x01, 0x30, 0x02, 0x2d, 0x0e, 0x10,
        0x51, 0x33, 0x39, 0x38, 0x31, 0x35, 0x32, 0x49, 0x6d, 0x98, 0xee, 0x5a, 0x00,
    ];
    const GOLDEN_START: &[u8] = &[0x01, 0x05, 0x51, 0x53, 0x7d, 0x52, 0x00];
    const GOLDEN_RATE: &[u8] = &[8, 2, 144, 78, 148, 88, 14, 6, 0];
    const GOLDEN_PING: &[u8] = &[11, 5, 239, 253, 182, 245, 13, 155, 120, 43, 223, 0];
    const GOLDEN_ARM_INDEX: &[u8] = &[6, 7, 186, 55, 183, 134, 0];

    #[test]
    fn worst_case_messages_fit_max_frame() {
        let worst = Sample {
            t_us: u64::MAX,
            enc1: i64::MIN,
            enc2: i64::MIN,
            d_mm: f64::MAX,
            status: Status(0xff),
        };
        let mut samples = heapless::Vec::new();
        for _ in 0..BATCH_LEN {
            samples.push(worst).unwrap();
        }
        let batch = DeviceMsg::Batch(SampleBatch {
            seq: u32::MAX,
            dropped: u32::MAX,
            samples,
        });
        let n = enc_vec(&batch).len();
        assert!(n <= MAX_FRAME_LEN, "{n}");
        let enc = EncoderCal {
            counts_per_rev: u32::MAX,
            zero_count: i64::MIN,
            direction: Direction::Negative,
            zero_offset_rad: f64::MAX,
            eccentricity_rad: f64::MAX,
            eccentricity_phase_rad: f64::MAX,
        };
        let frame = FrameCal {
            tilt_rad: f64::MAX,
            offset_normal_rad: f64::MAX,
            offset_axial_rad: f64::MAX,
        };
        let cal = Calibration {
            l1_mm: f64::MAX,
            l2_mm: f64::MAX,
            enc1: enc,
            enc2: enc,
            axes_skew_rad: f64::MAX,
            frame1: frame,
            frame2: frame,
        };
        assert!(enc_vec(&Command::SetCalibration(cal)).len() <= MAX_FRAME_LEN);
        let worst_index = IndexStatus {
            reference: Reference::Zero,
            armed: true,
            passes: u32::MAX,
            last_pass_count: i64::MIN,
        };
        let info = DeviceMsg::Info(DeviceInfo {
            protocol_version: u16::MAX,
            firmware_version: [u8::MAX; 3],
            board: Board::QemuNetduinoPlus2,
            sample_rate_hz: u32::MAX,
            sampling: true,
            calibration: cal,
            chip_id: [0xff; 12],
            reset_cause: ResetCause(0xff),
            index: [worst_index; 2],
            overruns: u32::MAX,
            clock: ClockSource::Emulated,
            calibration_kept: CalKept::ReadBackDiffers,
            unhandled_irq: Some(i16::MIN),
            index_disabled: [true; 2],
        });
        assert!(enc_vec(&info).len() <= MAX_FRAME_LEN);
    }

    /// Issue 32 §3: the link's load at 5, 10 and 20 kHz, from the frames the device sends: full
    /// batches of realistic samples an hour into a run (t_us 5 varint bytes, counts of a 2²³
    /// counts/rev encoder 4 bytes, D 8 bytes).
    #[test]
    fn throughput_budget() {
        let mut samples = heapless::Vec::new();
        for i in 0..BATCH_LEN as u64 {
            samples
                .push(Sample {
                    t_us: 3_600_000_000 + 50 * i,
                    enc1: 1_500_000 + 3 * i as i64,
                    enc2: -2_700_000 - 5 * i as i64,
                    d_mm: 100.012_345 + 1e-6 * i as f64,
                    status: Status(Status::ENC1_REFERENCED | Status::ENC2_REFERENCED),
                })
                .unwrap();
        }
        let batch = DeviceMsg::Batch(SampleBatch {
            seq: 72_000_000,
            dropped: 3,
            samples,
        });
        let frame = enc_vec(&batch).len();
        let per_sample = frame as f64 / BATCH_LEN as f64;
        assert!((22.0..=24.0).contains(&per_sample), "{frame} bytes a batch");
        for (hz, max_kb_s) in [(5_000.0, 120.0), (10_000.0, 240.0), (20_000.0, 480.0)] {
            let bytes_s = per_sample * hz;
            let packets_s = (bytes_s / 64.0).ceil();
            assert!(bytes_s / 1e3 <= max_kb_s, "{hz} Hz: {bytes_s} B/s");
            std::println!(
                "{hz} Hz: {frame} B per {BATCH_LEN}-sample frame, {:.0} kB/s, {packets_s} packets/s",
                bytes_s / 1e3
            );
        }
    }

    #[test]
    fn corrupt_frame_is_rejected_by_crc_and_stream_resyncs() {
        let mut bytes = enc_vec(&golden_batch());
        bytes[5] ^= 0x40;
        if bytes[5] == 0 {
            bytes[5] = 1;
        }
        bytes.extend(enc_vec(&golden_info()));
        let out = decode_all::<DeviceMsg>(&bytes);
        assert_eq!(out.len(), 2);
        assert!(matches!(
            out[0],
            Err(FrameError::Crc) | Err(FrameError::Cobs)
        ));
        assert_eq!(out[1], Ok(golden_info()));
    }

    #[test]
    fn overlong_garbage_reported_once_then_resync() {
        let mut bytes = std::vec![0x55u8; 3 * MAX_FRAME_LEN];
        bytes.push(0);
        bytes.extend(enc_vec(&golden_batch()));
        let out = decode_all::<DeviceMsg>(&bytes);
        assert_eq!(
            out,
            std::vec![Err(FrameError::Overflow), Ok(golden_batch())]
        );
    }

    proptest! {
        // A fixed seed: the same cases on every run, so a failure is reproducible and CI cannot
        // flake on a rare draw (a failing case found later is kept as its own test).
        #![proptest_config(ProptestConfig {
            rng_seed: proptest::test_runner::RngSeed::Fixed(7421),
            failure_persistence: None,
            ..ProptestConfig::default()
        })]
        #[test]
        fn batch_round_trip(seq in any::<u32>(), dropped in any::<u32>(),
                            raw in prop::collection::vec((any::<u64>(), any::<i64>(), any::<i64>(), -1e3f64..1e3, any::<u8>()), 0..=BATCH_LEN)) {
            let mut samples = heapless::Vec::new();
            for (t_us, enc1, enc2, d_mm, s) in raw {
                samples.push(Sample { t_us, enc1, enc2, d_mm, status: Status(s) }).unwrap();
            }
            let msg = DeviceMsg::Batch(SampleBatch { seq, dropped, samples });
            let out = decode_all::<DeviceMsg>(&enc_vec(&msg));
            prop_assert_eq!(out, std::vec![Ok(msg)]);
        }

        #[test]
        fn command_round_trip(hz in any::<u32>(), tok in any::<u32>(), l in 1.0f64..500.0, z in any::<i64>()) {
            let mut cal = Calibration::DEFAULT;
            cal.l1_mm = l;
            cal.enc2.zero_count = z;
            for c in [Command::Start, Command::Stop, Command::SetSampleRate(hz), Command::SetCalibration(cal),
                      Command::Zero, Command::Ping(tok), Command::GetInfo, Command::ArmIndex] {
                let out = decode_all::<Command>(&enc_vec(&c));
                prop_assert_eq!(out, std::vec![Ok(c)]);
            }
        }

        #[test]
        fn random_bytes_never_panic_and_resync(garbage in prop::collection::vec(any::<u8>(), 0..3000),
                                               split in 0usize..4000) {
            // Garbage, then a delimiter, then a valid frame: whatever the garbage, the valid frame
            // comes out, however the bytes are split across reads.
            let mut bytes = garbage;
            bytes.push(0);
            bytes.extend(enc_vec(&golden_batch()));
            let split = split.min(bytes.len());
            let mut d = Decoder::<MAX_FRAME_LEN>::new();
            let mut out = std::vec::Vec::new();
            d.feed::<DeviceMsg>(&bytes[..split], |r| out.push(r));
            d.feed::<DeviceMsg>(&bytes[split..], |r| out.push(r));
            prop_assert_eq!(out.last(), Some(&Ok(golden_batch())));
        }
    }
}
