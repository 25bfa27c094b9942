//! QEMU only: a scenario file ([`jdbb_core::scenario`]) played as the simulated encoders, read over
//! semihosting from the host's file system.
//!
//! `scripts/qemu-run.sh --scenario FILE` starts QEMU with the semihosting command line
//! `jdbb-firmware FILE`; at boot [`Scenario::from_command_line`] opens FILE. Without a second
//! word on the command line the build runs its built-in circle. The file is read in blocks of
//! [`BLOCK_RECORDS`] records as the samples need them (a semihosting call stops the emulated CPU
//! only while QEMU reads the host file, which under `-icount` takes no emulated time); a new run
//! (time going back) seeks back to the record it needs.

use cortex_m_semihosting::{nr, syscall};
use jdbb_core::scenario::{decode_record, Header, ScenarioError, HEADER_LEN, RECORD_LEN};

/// Records read per semihosting call.
pub const BLOCK_RECORDS: usize = 256;
const PATH_MAX: usize = 256;

/// A command-line argument that is not a scenario: `flash-fault=MODE` makes the QEMU build's
/// calibration flash fail (see `board::qemu`, `FlashFault`).
pub const FLASH_FAULT_ARG: &[u8] = b"flash-fault=";

/// The `flash-fault=` argument's value (`MODE`) on the semihosting command line, if any, into
/// `buf`.
pub fn flash_fault_arg(buf: &mut [u8; 32]) -> Option<&[u8]> {
    let mut line = [0u8; PATH_MAX];
    let block = [line.as_mut_ptr() as usize, line.len() - 1];
    // SAFETY: SYS_GET_CMDLINE writes at most block[1] bytes and a NUL into `line`.
    if unsafe { syscall(nr::GET_CMDLINE, &block) } != 0 {
        return None;
    }
    let end = line.iter().position(|&b| b == 0).unwrap_or(line.len());
    let space = line[..end].iter().position(|&b| b == b' ')?;
    let arg = line[space + 1..end].strip_prefix(FLASH_FAULT_ARG)?;
    let n = arg.len().min(buf.len());
    buf[..n].copy_from_slice(&arg[..n]);
    Some(&buf[..n])
}

/// Why the scenario named on the command line cannot be played.
#[derive(Debug, Clone, Copy, PartialEq, Eq, defmt::Format)]
pub enum OpenError {
    /// The command line is longer than the firmware's buffer (256 bytes).
    CommandLineTooLong,
    /// The host could not open the file (it does not exist or cannot be read).
    Open,
    /// The file's header is not a scenario header.
    Header(ScenarioError),
    /// The file is shorter than its header says.
    Short,
}

impl OpenError {
    /// What went wrong and what to do, for the person who started QEMU.
    pub fn describe(&self) -> &'static str {
        match self {
            OpenError::CommandLineTooLong => {
                "the path is too long (at most 250 bytes): move the file"
            }
            OpenError::Open => "QEMU could not open the file on the host",
            OpenError::Header(ScenarioError::Truncated) => "the file is shorter than a header",
            OpenError::Header(ScenarioError::BadMagic) => "not a scenario file (no JDBBSCEN)",
            OpenError::Header(ScenarioError::UnsupportedVersion(_)) => {
                "written for another version of the scenario format: write it again"
            }
            OpenError::Header(ScenarioError::Reserved) => "reserved header bytes are not zero",
            OpenError::Header(ScenarioError::ZeroPeriod) => "the header's period is 0 µs",
            OpenError::Header(ScenarioError::Empty) => "the header says 0 records",
            OpenError::Short => {
                "the file is shorter than its header says (cut off while it was written?)"
            }
        }
    }
}

/// An open scenario file and the block of records last read from it.
pub struct Scenario {
    fd: usize,
    header: Header,
    block: [u8; BLOCK_RECORDS * RECORD_LEN],
    /// Index of the block's first record.
    first: u32,
    /// Records in the block.
    len: u32,
}

impl Scenario {
    /// The scenario named by the second word of the semihosting command line, if there is one.
    pub fn from_command_line() -> Option<Result<Scenario, OpenError>> {
        let mut line = [0u8; PATH_MAX];
        let block = [line.as_mut_ptr() as usize, line.len() - 1];
        // SAFETY: SYS_GET_CMDLINE writes at most block[1] bytes and a NUL into `line`.
        let rc = unsafe { syscall(nr::GET_CMDLINE, &block) };
        if rc != 0 {
            return None;
        }
        let end = line.iter().position(|&b| b == 0).unwrap_or(line.len());
        if end >= line.len() - 1 {
            return Some(Err(OpenError::CommandLineTooLong));
        }
        // The first word is the program's name; the rest (spaces included) is the path.
        let space = line[..end].iter().position(|&b| b == b' ')?;
        let path = &line[space + 1..=end]; // NUL-terminated
        if path.len() <= 1 || path.starts_with(FLASH_FAULT_ARG) {
            return None;
        }
        Some(Self::open(path))
    }

    /// Open the NUL-terminated `path` and check its header and length.
    fn open(path: &[u8]) -> Result<Scenario, OpenError> {
        // Mode 1: "rb".
        // SAFETY: `path` is NUL-terminated and its length excludes the NUL, as SYS_OPEN wants.
        let fd = unsafe { syscall!(OPEN, path.as_ptr(), 1, path.len() - 1) };
        if fd == usize::MAX {
            return Err(OpenError::Open);
        }
        let mut s = Scenario {
            fd,
            header: Header {
                period_us: 1,
                n_samples: 1,
            },
            block: [0; BLOCK_RECORDS * RECORD_LEN],
            first: 0,
            len: 0,
        };
        let mut head = [0u8; HEADER_LEN];
        if !read_exact(s.fd, &mut head) {
            return Err(OpenError::Header(ScenarioError::Truncated));
        }
        s.header = Header::decode(&head).map_err(OpenError::Header)?;
        // SAFETY: SYS_FLEN on the handle just opened.
        let len = unsafe { syscall!(FLEN, s.fd) };
        if len == usize::MAX || (len as u64) < s.header.file_len() {
            return Err(OpenError::Short);
        }
        s.load(0);
        Ok(s)
    }

    /// The header.
    pub fn header(&self) -> Header {
        self.header
    }

    /// The counters' raw values of the sample taken at `t_us` after the run's start.
    #[inline]
    pub fn raw_at(&mut self, t_us: u64) -> [u32; 2] {
        let k = self.header.record_at(t_us);
        if k < self.first || k >= self.first + self.len {
            self.load(k);
        }
        let i = (k - self.first) as usize * RECORD_LEN;
        let mut r = [0u8; RECORD_LEN];
        r.copy_from_slice(&self.block[i..i + RECORD_LEN]);
        decode_record(&r)
    }

    /// Read the block that starts at record `k`.
    #[cold]
    fn load(&mut self, k: u32) {
        let n = (self.header.n_samples - k).min(BLOCK_RECORDS as u32);
        let pos = HEADER_LEN + k as usize * RECORD_LEN;
        // SAFETY: SYS_SEEK on our handle to a position inside the file (checked at open).
        unsafe { syscall!(SEEK, self.fd, pos) };
        let bytes = n as usize * RECORD_LEN;
        let ok = read_exact(self.fd, &mut self.block[..bytes]);
        self.first = k;
        // The length was checked at open; a file cut short since leaves the counters where the
        // block's readable part ends.
        self.len = if ok { n } else { 1 };
    }
}

/// Fill `buf` from the host file `fd`; false if the file ended first.
fn read_exact(fd: usize, buf: &mut [u8]) -> bool {
    // SAFETY: SYS_READ writes at most buf.len() bytes into buf; returns how many were not read.
    let left = unsafe { syscall!(READ, fd, buf.as_mut_ptr(), buf.len()) };
    left == 0
}
