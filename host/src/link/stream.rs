//! Frames from a J-DBB → decoded samples, with the accounting that tells whether anything was
//! lost on the way.
//!
//! [`Stream`] wraps any byte source (`std::io::Read`): the serial port [`open_port`] returns (a USB
//! CDC-ACM device, or the pty QEMU prints as `char device redirected to /dev/pts/N`), a file, or an
//! in-memory slice in tests and benchmarks. It feeds the bytes to the shared
//! [`Decoder`](jdbb_core::protocol::Decoder), hands every sample batch to the caller with each
//! sample's sequence number, and keeps [`Stats`]:
//!
//! - `frames_ok`, and corrupt frames by kind (CRC, COBS, overflow, payload): corrupt frames are
//!   counted and skipped, the decoder resynchronises at the next 0x00. A port opened while the
//!   device is sending starts in the middle of a frame: that first, cut frame is counted as
//!   `partial`, not as corrupt.
//! - `samples` received, `lost`: sequence numbers never received. The device numbers every sample
//!   it takes, including those it drops itself when its queue is full, so `lost` includes
//!   `device_dropped` (the device's own count); `lost − device_dropped` is what the link lost.
//! - `resets`: the device restarted without being asked — its sequence number or clock went
//!   backwards, or it announced itself ([`DeviceMsg::Info`]) unprompted. A restart the host asked
//!   for with [`Command::Start`] is not a reset. The latest one is described by
//!   [`Stream::last_restart`].
//! - `before_start`: samples discarded because they were taken before the device acknowledged
//!   the [`Command::Start`] this stream sent (see below).
//!
//! **One run.** After [`Stream::send`]`(&Command::Start)` no batch is delivered until the device
//! has answered that Start (every command is answered, in order, by one [`DeviceMsg::Info`] or
//! [`DeviceMsg::Rejected`], on the same queue as the batches): what comes before the answer
//! belongs to the run that was going on, even if its sequence numbers are small; the first batch
//! after it begins the new run (seq 0). [`Stream::check_start`] says when the answer is overdue or
//! was a refusal. With [`Stream::set_one_run`], nothing is delivered after a device restart either,
//! so that the samples delivered are exactly one run: a recording never stitches two.
//!
//! The sequence number on the wire is a `u32`; [`SeqSample::seq`] extends it to `u64` across wraps
//! (at 10 kHz a `u32` wraps after 5 days) and restarts at the device's value after a restart.
use std::io::{self, Read, Write};
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, OnceLock};
use std::time::{Duration, Instant};

use jdbb_core::protocol::{
    self, ClockSource, Command, CommandError, DeviceInfo, DeviceMsg, FrameError, Hello, Sample,
    SampleBatch, MAX_FRAME_LEN,
};

use crate::{Error, Result};

/// Bytes asked for per read. Large enough that one read holds many batches at 20 kHz.
const READ_CHUNK: usize = 16 * 1024;

/// How long a read on a serial port waits for data before [`Stream::poll`] returns
/// [`Poll::Idle`]; bounds how late Ctrl-C or `--seconds` take effect.
pub const READ_TIMEOUT: Duration = Duration::from_millis(50);

/// An [`DeviceMsg::Info`] arriving this long after a command was sent is taken as its reply; any
/// other Info after samples have flowed means the device restarted. As long as
/// [`START_ACK_TIMEOUT`]: a reply can wait behind the device's erase ahead.
const INFO_REPLY_WINDOW: Duration = Duration::from_secs(5);

/// How long after [`Command::Start`] the device has to acknowledge it (answer with its Info): it
/// covers the device's erase ahead of its calibration store (up to 4 s with the CPU stalled), which
/// it starts only while the link is quiet, so a Start sent just then is answered late, not lost
/// ([`crate::link::calibration::REPLY_TIMEOUT`]).
pub const START_ACK_TIMEOUT: Duration = Duration::from_secs(5);

/// How often [`Stream::handshake`] repeats its ping.
pub const HANDSHAKE_RESEND: Duration = Duration::from_millis(250);

/// One received sample with its sequence number.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SeqSample {
    /// Sequence number: the batch's `seq` + index in the batch, extended across `u32` wraps.
    pub seq: u64,
    /// The sample as the device sent it.
    pub sample: Sample,
}

/// Corrupt frames by the reason they were rejected.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct CorruptFrames {
    /// The CRC did not match (or the frame was shorter than its CRC).
    pub crc: u64,
    /// The bytes between two delimiters were not valid COBS.
    pub cobs: u64,
    /// More than [`MAX_FRAME_LEN`] bytes without a delimiter (garbage, or a lost delimiter).
    pub overflow: u64,
    /// Valid CRC but not a known message (e.g. a firmware speaking another protocol version).
    pub payload: u64,
}

impl CorruptFrames {
    /// All corrupt frames.
    pub fn total(&self) -> u64 {
        self.crc + self.cobs + self.overflow + self.payload
    }
}

/// What a [`Stream`] has seen so far.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Stats {
    /// Bytes read from the source.
    pub bytes: u64,
    /// Frames that decoded to a known message.
    pub frames_ok: u64,
    /// Frames rejected, by reason.
    pub corrupt: CorruptFrames,
    /// Samples received.
    pub samples: u64,
    /// Sequence numbers skipped: samples taken by the device but never received (includes the
    /// samples the device dropped itself).
    pub lost: u64,
    /// Samples the device reports it dropped (queue full), summed over its restarts.
    pub device_dropped: u64,
    /// Unrequested device restarts seen.
    pub resets: u64,
    /// [`DeviceMsg::Pong`] replies received.
    pub pongs: u64,
    /// Commands the device refused ([`DeviceMsg::Rejected`]).
    pub rejected: u64,
    /// The first frame, when it was cut because the port was opened while the device was sending
    /// (0 or 1): not valid, but not a corruption of the link either.
    pub partial: u64,
    /// Samples received before the device acknowledged this stream's Start, from the run that
    /// was going on: discarded.
    pub before_start: u64,
}

impl std::fmt::Display for Stats {
    /// One line: `samples N, lost N (device dropped N), corrupt frames N (crc N, cobs N, overflow
    /// N, payload N), resets N, partial first frame N, discarded before start N`. `partial first
    /// frame` is the frame cut by opening the port mid-stream (not counted as corrupt);
    /// `discarded before start` the samples of the run before this session's Start.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let c = &self.corrupt;
        write!(
            f,
            "samples {}, lost {} (device dropped {}), corrupt frames {} (crc {}, cobs {}, overflow {}, payload {}), resets {}, partial first frame {}, discarded before start {}",
            self.samples,
            self.lost,
            self.device_dropped,
            c.total(),
            c.crc,
            c.cobs,
            c.overflow,
            c.payload,
            self.resets,
            self.partial,
            self.before_start
        )
    }
}

/// How the device showed that it restarted.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RestartCause {
    /// The sequence number went back: `expected` was due, `got` came.
    SeqBack { expected: u64, got: u32 },
    /// The clock went back (or stood still): a sample at `got` µs after one at `last` µs.
    ClockBack { last: u64, got: u64 },
    /// The device described itself ([`DeviceMsg::Info`]) without being asked.
    Announced,
    /// The device greeted the host ([`DeviceMsg::Hello`]), which it does only after a restart or
    /// a new connection.
    Greeted,
}

/// A device restart seen while samples were flowing, and the last sample before it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Restart {
    /// How it showed.
    pub cause: RestartCause,
    /// The last sample delivered before it (None if none was).
    pub last: Option<SeqSample>,
}

impl std::fmt::Display for Restart {
    /// e.g. `the device restarted (sequence went back: 4032 was due, 0 came) after seq 4031, t_us
    /// 4031000`.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self.cause {
            RestartCause::SeqBack { expected, got } => write!(
                f,
                "the device restarted (sequence went back: {expected} was due, {got} came)"
            )?,
            RestartCause::ClockBack { last, got } => write!(
                f,
                "the device restarted (clock went back: t_us {got} after {last})"
            )?,
            RestartCause::Announced => {
                write!(f, "the device restarted (it announced itself unasked)")?
            }
            RestartCause::Greeted => write!(f, "the device restarted (it sent its greeting)")?,
        }
        match self.last {
            Some(s) => write!(f, " after seq {}, t_us {}", s.seq, s.sample.t_us),
            None => write!(f, " before any sample"),
        }
    }
}

/// Where a stream stands with the run it started (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
enum Gate {
    /// Deliver what comes (no Start sent, or the run has begun).
    #[default]
    Open,
    /// Start sent, its answer is reply number `reply` (counted from 0) and has not come yet.
    AwaitAck { reply: u64, sent: Instant },
    /// Start acknowledged: the next batch begins the run.
    AwaitFirst,
    /// The device refused the Start.
    Refused(CommandError),
}

/// What one [`Stream::poll`] saw.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Poll {
    /// This many bytes were read and decoded.
    Data(usize),
    /// No data within the read timeout (serial ports only).
    Idle,
    /// End of stream: the source is exhausted (in-memory, file) or the device hung up.
    Closed,
}

/// Sequence and reset bookkeeping, separate from the decoder so both can be borrowed at once.
#[derive(Debug, Default)]
struct Tracker {
    stats: Stats,
    info: Option<DeviceInfo>,
    hello: Option<Hello>,
    last_sample: Option<SeqSample>,
    last_rejected: Option<CommandError>,
    last_pong: Option<u32>,
    /// The latest answer to a command: its number (counted from 0, as `replies_got`) and the
    /// Info or the refusal.
    last_reply: Option<(u64, std::result::Result<DeviceInfo, CommandError>)>,
    /// Extended sequence number expected next; None before the first batch.
    next_seq: Option<u64>,
    /// Time stamp of the last sample received.
    last_t_us: Option<u64>,
    /// Time stamp of the sample before it.
    before_last_t_us: Option<u64>,
    /// Dropped counts of the device's earlier sessions, and the latest count of the current one.
    dropped_before: u64,
    dropped_now: u32,
    /// The device announced a restart (counted already): the next backwards step of the
    /// sequence is expected and not a second reset.
    restart_expected: bool,
    /// Until when an Info is taken as the reply to a command.
    info_reply_until: Option<Instant>,
    /// Commands sent that the device answers with Info or Rejected, and answers received.
    replies_asked: u64,
    replies_got: u64,
    /// Where the run this stream started stands.
    gate: Gate,
    /// A frame (valid or not) has ended since the stream was opened.
    seen_frame: bool,
    /// Stop delivering at the first restart ([`Stream::set_one_run`]).
    one_run: bool,
    /// The one run ended with a restart: nothing more is delivered.
    ended: bool,
    /// The latest restart seen.
    last_restart: Option<Restart>,
    /// Reused per batch.
    batch: Vec<SeqSample>,
}

impl Tracker {
    fn on_frame(
        &mut self,
        frame: std::result::Result<DeviceMsg, FrameError>,
        on_batch: &mut impl FnMut(&[SeqSample]),
    ) {
        let first = !self.seen_frame;
        self.seen_frame = true;
        let msg = match frame {
            Ok(msg) => msg,
            Err(_) if first => {
                // The port was opened in the middle of a frame: its tail is all we saw.
                self.stats.partial += 1;
                return;
            }
            Err(e) => {
                let c = &mut self.stats.corrupt;
                match e {
                    FrameError::Crc => c.crc += 1,
                    FrameError::Cobs => c.cobs += 1,
                    FrameError::Overflow => c.overflow += 1,
                    // `Payload`, and kinds a later jdbb-core may add (the enum is non-exhaustive;
                    // `BufferFull` is an encoding error and never comes from the decoder).
                    _ => c.payload += 1,
                }
                return;
            }
        };
        self.stats.frames_ok += 1;
        match msg {
            DeviceMsg::Batch(batch) => self.on_batch(&batch, on_batch),
            DeviceMsg::Info(info) => {
                let n = self.replies_got;
                let answer = self.take_reply(None);
                if answer {
                    self.last_reply = Some((n, Ok(info)));
                }
                let solicited = answer
                    || self
                        .info_reply_until
                        .is_some_and(|until| Instant::now() <= until);
                if !solicited && self.running() {
                    // Samples flowed and the device announces itself unprompted: it restarted.
                    // Its sequence restarts too; don't count that restart a second time.
                    self.on_restart(RestartCause::Announced);
                    self.restart_expected = true;
                }
                self.info = Some(info);
            }
            DeviceMsg::Hello(hello) => {
                // The greeting is never a reply: after samples flowed, the device restarted.
                if self.running() {
                    self.on_restart(RestartCause::Greeted);
                    self.restart_expected = true;
                }
                self.hello = Some(hello);
            }
            DeviceMsg::Pong(token) => {
                self.stats.pongs += 1;
                self.last_pong = Some(token);
            }
            DeviceMsg::Rejected(e) => {
                let n = self.replies_got;
                if self.take_reply(Some(e)) {
                    self.last_reply = Some((n, Err(e)));
                }
                self.stats.rejected += 1;
                self.last_rejected = Some(e);
            }
        }
    }

    /// Samples of a run are flowing (a restart now would split it).
    fn running(&self) -> bool {
        self.gate == Gate::Open && self.next_seq.is_some() && !self.ended
    }

    /// Count a restart seen while running; in one-run mode, end the run.
    fn on_restart(&mut self, cause: RestartCause) {
        self.stats.resets += 1;
        self.last_restart = Some(Restart {
            cause,
            last: self.last_sample,
        });
        if self.one_run {
            self.ended = true;
        }
    }

    /// Take an Info (`rejected` None) or Rejected as the answer to the oldest command not yet
    /// answered, if there is one; returns whether there was. The answer to a Start opens the gate
    /// for the new run (or records the refusal).
    fn take_reply(&mut self, rejected: Option<CommandError>) -> bool {
        if self.replies_got >= self.replies_asked {
            return false;
        }
        let n = self.replies_got;
        self.replies_got += 1;
        if let Gate::AwaitAck { reply, .. } = self.gate {
            if reply == n {
                self.gate = match rejected {
                    None => Gate::AwaitFirst,
                    Some(e) => Gate::Refused(e),
                };
            }
        }
        true
    }

    fn on_batch(&mut self, b: &SampleBatch, on_batch: &mut impl FnMut(&[SeqSample])) {
        match self.gate {
            Gate::AwaitAck { .. } | Gate::Refused(_) => {
                // Taken before the device restarted for our Start: another run.
                self.stats.before_start += b.samples.len() as u64;
                return;
            }
            Gate::AwaitFirst => {
                // The first batch after the answer to Start: the run begins (at seq 0, unless
                // the link lost its first batches, which then count as lost).
                self.gate = Gate::Open;
                self.next_seq = None;
                self.last_t_us = None;
                self.before_last_t_us = None;
                self.last_sample = None;
                self.restart_expected = false;
                self.stats.lost += u64::from(b.seq);
                self.dropped_before = 0;
                self.dropped_now = 0;
            }
            Gate::Open => {}
        }
        if self.ended {
            return;
        }
        let first_seq = match self.next_seq {
            // The first batch: of a run joined while it was going on (listening without Start:
            // what came before is not counted as lost), or of the run our Start began (its
            // missing first batches were counted above).
            None => {
                self.dropped_now = b.dropped;
                u64::from(b.seq)
            }
            Some(next) => {
                let forward = b.seq.wrapping_sub(next as u32);
                let seq_back = forward >= 1 << 31;
                // Back from the sample before the last too: one corrupted time (2⁶⁴ − 1) as a
                // batch's last sample is not a restart (the recorder marks it as suspect).
                let time_back = match (b.samples.first(), self.last_t_us) {
                    (Some(s), Some(t))
                        if s.t_us <= t && self.before_last_t_us.is_none_or(|p| s.t_us <= p) =>
                    {
                        Some((t, s.t_us))
                    }
                    _ => None,
                };
                if seq_back || time_back.is_some() {
                    // A new sampling session: sequence numbers restart at 0, so the ones before
                    // this batch were taken and never received.
                    if !self.restart_expected {
                        self.on_restart(match time_back {
                            Some((last, got)) if !seq_back => RestartCause::ClockBack { last, got },
                            _ => RestartCause::SeqBack {
                                expected: next,
                                got: b.seq,
                            },
                        });
                    } else if self.one_run {
                        // Announced already (and counted): the run ended there.
                        self.ended = true;
                    }
                    self.restart_expected = false;
                    if self.ended {
                        return;
                    }
                    self.stats.lost += u64::from(b.seq);
                    self.dropped_before += u64::from(self.dropped_now);
                    self.dropped_now = b.dropped;
                    u64::from(b.seq)
                } else {
                    self.stats.lost += u64::from(forward);
                    self.dropped_now = self.dropped_now.max(b.dropped);
                    next + u64::from(forward)
                }
            }
        };
        self.stats.device_dropped = self.dropped_before + u64::from(self.dropped_now);
        let n = b.samples.len();
        self.next_seq = Some(first_seq + n as u64);
        if n == 0 {
            return;
        }
        self.batch.clear();
        self.batch
            .extend(b.samples.iter().enumerate().map(|(i, s)| SeqSample {
                seq: first_seq + i as u64,
                sample: *s,
            }));
        self.stats.samples += n as u64;
        self.before_last_t_us = match n {
            1 => self.last_t_us,
            _ => Some(b.samples[n - 2].t_us),
        };
        self.last_t_us = Some(b.samples[n - 1].t_us);
        self.last_sample = self.batch.last().copied();
        on_batch(&self.batch);
    }
}

/// Decoded samples and statistics from one byte source (see the module docs).
///
/// ```
/// use jdbb::link::stream::{Poll, Stream};
/// let bytes: &[u8] = &[]; // frames made with jdbb_core::protocol::encode
/// let mut stream = Stream::new(bytes, "example");
/// let mut samples = Vec::new();
/// while stream.poll(|batch| samples.extend_from_slice(batch)).unwrap() != Poll::Closed {}
/// assert_eq!(stream.stats().samples, samples.len() as u64);
/// ```
pub struct Stream<P> {
    port: P,
    name: String,
    decoder: protocol::Decoder<MAX_FRAME_LEN>,
    tracker: Tracker,
    buf: Vec<u8>,
    closed: bool,
}

impl<P> Stream<P> {
    /// A stream over `port`; `name` (the port's path) appears in error messages.
    pub fn new(port: P, name: impl Into<String>) -> Self {
        Stream {
            port,
            name: name.into(),
            decoder: protocol::Decoder::new(),
            tracker: Tracker::default(),
            buf: vec![0; READ_CHUNK],
            closed: false,
        }
    }

    /// Decode bytes obtained elsewhere (the same as if [`Stream::poll`] had read them);
    /// `on_batch` is called once per sample batch, in order.
    pub fn feed(&mut self, bytes: &[u8], mut on_batch: impl FnMut(&[SeqSample])) {
        self.tracker.stats.bytes += bytes.len() as u64;
        let tracker = &mut self.tracker;
        self.decoder
            .feed::<DeviceMsg>(bytes, |frame| tracker.on_frame(frame, &mut on_batch));
    }

    /// Counts so far.
    pub fn stats(&self) -> &Stats {
        &self.tracker.stats
    }

    /// The latest [`DeviceInfo`] the device sent, if any.
    pub fn info(&self) -> Option<&DeviceInfo> {
        self.tracker.info.as_ref()
    }

    /// The device's latest greeting ([`DeviceMsg::Hello`]), if one was received.
    pub fn hello(&self) -> Option<&Hello> {
        self.tracker.hello.as_ref()
    }

    /// The most recent sample received.
    pub fn last_sample(&self) -> Option<&SeqSample> {
        self.tracker.last_sample.as_ref()
    }

    /// The reason of the latest refused command.
    pub fn last_rejected(&self) -> Option<CommandError> {
        self.tracker.last_rejected
    }

    /// Token of the latest [`DeviceMsg::Pong`].
    pub fn last_pong(&self) -> Option<u32> {
        self.tracker.last_pong
    }

    /// Bytes of an unfinished frame held by the decoder (not yet decoded; lost if the stream
    /// ends here).
    pub fn pending_bytes(&self) -> usize {
        self.decoder.pending()
    }

    /// Deliver one run only: after a device restart, no more batches (the default delivers the
    /// new run's batches too, and counts the reset). See [`Stream::run_ended`].
    pub fn set_one_run(&mut self, on: bool) {
        self.tracker.one_run = on;
    }

    /// In one-run mode: the run ended with this restart, and nothing after it was delivered.
    pub fn run_ended(&self) -> Option<&Restart> {
        if self.tracker.ended {
            self.tracker.last_restart.as_ref()
        } else {
            None
        }
    }

    /// The latest device restart seen while samples were flowing (counted in `resets`).
    pub fn last_restart(&self) -> Option<&Restart> {
        self.tracker.last_restart.as_ref()
    }

    /// Whether the run this stream started (with [`Command::Start`]) has begun delivering, or no
    /// Start was sent.
    pub fn run_begun(&self) -> bool {
        self.tracker.gate == Gate::Open
    }

    /// After [`Command::Start`]: an error if the device refused it, or has not acknowledged it
    /// within [`START_ACK_TIMEOUT`] (no sample is delivered until it does). Ok otherwise.
    pub fn check_start(&self) -> Result<()> {
        match self.tracker.gate {
            Gate::Refused(reason) => Err(Error::StartRefused {
                port: self.name.clone(),
                reason: format!("{reason:?}"),
            }),
            Gate::AwaitAck { sent, .. } if sent.elapsed() > START_ACK_TIMEOUT => {
                Err(Error::StartNotAcknowledged {
                    port: self.name.clone(),
                    seconds: START_ACK_TIMEOUT.as_secs(),
                })
            }
            _ => Ok(()),
        }
    }

    /// The port's name as given to [`Stream::new`].
    pub fn name(&self) -> &str {
        &self.name
    }

    /// The underlying port.
    pub fn get_mut(&mut self) -> &mut P {
        &mut self.port
    }

    /// The underlying port, giving up the stream.
    pub fn into_inner(self) -> P {
        self.port
    }
}

impl Stream<Box<dyn serialport::SerialPort>> {
    /// [`open_port`] and wrap it: the usual way to stream from a device or QEMU's pty.
    ///
    /// Bytes already waiting in the port (left from an earlier session: the pty or USB buffer
    /// keeps what no one read) are discarded, so that a new recording starts with this session.
    pub fn open(port: &str) -> Result<Self> {
        let p = open_port(port)?;
        // Best effort: a port that cannot clear its buffer still streams correctly; stale frames
        // would then show as a joined stream and at worst one partial frame.
        let _ = p.clear(serialport::ClearBuffer::Input);
        Ok(Stream::new(p, port))
    }
}

impl<P: Read> Stream<P> {
    /// Read once from the port (waiting at most [`READ_TIMEOUT`] on a serial port), decode, and
    /// call `on_batch` with each complete sample batch. Once [`Poll::Closed`] is returned, every
    /// later call returns it too.
    ///
    /// A read error (the device was unplugged) is returned as [`Error::PortRead`]; everything
    /// decoded before it has already been handed to `on_batch`.
    pub fn poll(&mut self, on_batch: impl FnMut(&[SeqSample])) -> Result<Poll> {
        if self.closed {
            return Ok(Poll::Closed);
        }
        let mut buf = std::mem::take(&mut self.buf);
        let r = self.port.read(&mut buf);
        let out = match r {
            Ok(0) => {
                self.closed = true;
                Ok(Poll::Closed)
            }
            Ok(n) => {
                self.feed(&buf[..n], on_batch);
                Ok(Poll::Data(n))
            }
            Err(e)
                if matches!(
                    e.kind(),
                    io::ErrorKind::TimedOut
                        | io::ErrorKind::WouldBlock
                        | io::ErrorKind::Interrupted
                ) =>
            {
                Ok(Poll::Idle)
            }
            Err(source) => {
                self.closed = true;
                Err(Error::PortRead {
                    port: self.name.clone(),
                    source,
                })
            }
        };
        self.buf = buf;
        out
    }

    /// Poll until at least `n` samples have arrived, the source closes, or `timeout` passes —
    /// whichever comes first; returns every sample decoded meanwhile, in order (whole reads, so
    /// possibly more than `n`). For scripted use and tests, e.g. collecting 10 000 samples
    /// from QEMU after [`Stream::send`]`(&Command::Start)`.
    pub fn collect(&mut self, n: usize, timeout: Duration) -> Result<Vec<SeqSample>> {
        let t0 = Instant::now();
        let mut out = Vec::with_capacity(n);
        while out.len() < n && t0.elapsed() < timeout {
            if self.poll(|batch| out.extend_from_slice(batch))? == Poll::Closed {
                break;
            }
        }
        Ok(out)
    }
}

impl<P: Read + Write> Stream<P> {
    /// Wait until the device answers: send [`Command::Ping`] every [`HANDSHAKE_RESEND`] until its
    /// [`DeviceMsg::Pong`] comes back, at most `timeout`. Returns whether it did.
    ///
    /// For a session that is about to send `Start`: a QEMU pty drops what the firmware writes
    /// until QEMU notices the host opened it (up to a second), and a USB device may still be
    /// enumerating, so a reply to a command sent at once can be lost. Samples decoded while
    /// waiting belong to the session before `Start`; they are discarded and the counts start
    /// afresh (what the device said about itself is kept).
    pub fn handshake(&mut self, timeout: Duration) -> Result<bool> {
        let t0 = Instant::now();
        // A token of this session, so that a pong left from an earlier one does not count.
        let token = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0x4A44_4242, |d| d.subsec_nanos() ^ d.as_secs() as u32);
        let mut sent_at: Option<Instant> = None;
        let mut answered = false;
        while t0.elapsed() < timeout {
            if sent_at.is_none_or(|t| t.elapsed() >= HANDSHAKE_RESEND) {
                self.send(&Command::Ping(token))?;
                sent_at = Some(Instant::now());
            }
            if self.poll(|_| {})? == Poll::Closed {
                break;
            }
            if self.tracker.last_pong == Some(token) {
                answered = true;
                break;
            }
        }
        let old = std::mem::take(&mut self.tracker);
        let t = &mut self.tracker;
        t.info = old.info;
        t.hello = old.hello;
        t.last_pong = old.last_pong;
        t.last_reply = old.last_reply;
        // Commands and answers stay paired; a cut first frame stays reported.
        t.replies_asked = old.replies_asked;
        t.replies_got = old.replies_got;
        t.info_reply_until = old.info_reply_until;
        t.gate = old.gate;
        t.seen_frame = old.seen_frame;
        t.one_run = old.one_run;
        t.stats.partial = old.stats.partial;
        Ok(answered)
    }
}

impl<P: Read + Write> Stream<P> {
    /// Send `command` and wait, at most `timeout`, for the device's answer to it: its
    /// [`DeviceInfo`] (accepted, the state after the command) or the reason it refused
    /// (`Err` inside `Ok`). Not for [`Command::Ping`], which is answered by a Pong
    /// ([`Stream::handshake`]). Batches decoded meanwhile are counted and dropped.
    ///
    /// [`Error::NoReply`] if no answer came in time or the port closed first.
    pub fn request(
        &mut self,
        command: &Command,
        timeout: Duration,
    ) -> Result<std::result::Result<DeviceInfo, CommandError>> {
        assert!(
            !matches!(command, Command::Ping(_)),
            "a Ping is answered by a Pong: use handshake"
        );
        let n = self.tracker.replies_asked;
        self.send(command)?;
        let t0 = Instant::now();
        loop {
            if let Some((k, reply)) = self.tracker.last_reply {
                if k == n {
                    return Ok(reply);
                }
            }
            if t0.elapsed() >= timeout || self.poll(|_| {})? == Poll::Closed {
                // One last look: the answer may have come with the final read.
                if let Some((k, reply)) = self.tracker.last_reply {
                    if k == n {
                        return Ok(reply);
                    }
                }
                return Err(Error::NoReply {
                    port: self.name.clone(),
                    command: command_name(command),
                    seconds: timeout.as_secs_f64(),
                });
            }
        }
    }
}

/// A command's name for messages: `SetCalibration`, `GetInfo`, ...
pub fn command_name(command: &Command) -> &'static str {
    match command {
        Command::Start => "Start",
        Command::Stop => "Stop",
        Command::SetSampleRate(_) => "SetSampleRate",
        Command::SetCalibration(_) => "SetCalibration",
        Command::Zero => "Zero",
        Command::Ping(_) => "Ping",
        Command::GetInfo => "GetInfo",
        Command::ArmIndex => "ArmIndex",
    }
}

impl<P: Write> Stream<P> {
    /// Send one command to the device. After [`Command::Start`] the device's sequence restarts;
    /// batches are delivered again from the first one after the device acknowledged the Start
    /// (module docs), and that restart is not counted as a reset.
    pub fn send(&mut self, command: &Command) -> Result<()> {
        let mut buf = [0u8; MAX_FRAME_LEN];
        let frame = protocol::encode(command, &mut buf)
            .map_err(|e| Error::Usage(format!("cannot encode {command:?}: {e}")))?;
        let write_err = |source| Error::PortWrite {
            port: self.name.clone(),
            source,
        };
        self.port.write_all(frame).map_err(write_err)?;
        self.port.flush().map_err(write_err)?;
        let t = &mut self.tracker;
        if !matches!(command, Command::Ping(_)) {
            // Answered (in order) by one Info or Rejected.
            if matches!(command, Command::Start) {
                t.gate = Gate::AwaitAck {
                    reply: t.replies_asked,
                    sent: Instant::now(),
                };
                t.ended = false;
            }
            t.replies_asked += 1;
            t.info_reply_until = Some(Instant::now() + INFO_REPLY_WINDOW);
        }
        Ok(())
    }
}

/// Open a serial port for streaming: a USB CDC-ACM device (`/dev/ttyACM0`, `COM3`) or a pty
/// (`/dev/pts/N`, as printed by QEMU). The line is set to raw 8N1; the baud rate is irrelevant for
/// both (USB and ptys run at their own speed). Reads time out after [`READ_TIMEOUT`].
///
/// A path that does not exist, or is a directory or a regular file, is refused with a message
/// that says so, before anything is opened.
pub fn open_port(path: &str) -> Result<Box<dyn serialport::SerialPort>> {
    let refuse = |kind, what: String| Error::PortOpen {
        port: path.to_string(),
        source: serialport::Error::new(kind, what),
    };
    #[cfg(unix)]
    match std::fs::metadata(Path::new(path)) {
        Err(e) if e.kind() == io::ErrorKind::NotFound => {
            return Err(refuse(
                serialport::ErrorKind::NoDevice,
                "no such port".into(),
            ));
        }
        Ok(m) if m.is_dir() => {
            return Err(refuse(
                serialport::ErrorKind::InvalidInput,
                "it is a directory, not a serial device".into(),
            ));
        }
        Ok(m) if m.is_file() => {
            return Err(refuse(
                serialport::ErrorKind::InvalidInput,
                "it is a regular file, not a serial device".into(),
            ));
        }
        _ => {}
    }
    let port = serialport::new(path, 115_200)
        .timeout(READ_TIMEOUT)
        .open()
        .map_err(|source| {
            // e.g. /dev/null: a device, but not a terminal (ENOTTY: "Inappropriate ioctl for
            // device", or "Not a typewriter" in older libcs).
            let d = source.description.to_lowercase();
            let source = if d.contains("ioctl") || d.contains("typewriter") {
                serialport::Error::new(
                    source.kind(),
                    format!("not a serial device ({})", source.description),
                )
            } else {
                source
            };
            Error::PortOpen {
                port: path.to_string(),
                source,
            }
        })?;
    // A terminal (the open above checked it is one) that another program holds too.
    #[cfg(target_os = "linux")]
    if let Some((pid, name)) = holders(Path::new(path)).into_iter().next() {
        return Err(refuse(
            serialport::ErrorKind::Io(io::ErrorKind::ResourceBusy),
            format!("in use by {name} (PID {pid})"),
        ));
    }
    Ok(port)
}

/// Other processes that have `path` open, as (PID, program name), from their `/proc/PID/fd`
/// links. A serial terminal that opened the port without the exclusive lock (minicom and screen
/// use UUCP lock files instead, which nothing else here honours) would otherwise share the
/// device's bytes with jdbb: each would read part of the stream, and the record would show it
/// as lost and corrupt frames. Processes of other users are seen only by root.
#[cfg(target_os = "linux")]
fn holders(path: &Path) -> Vec<(u32, String)> {
    let Ok(target) = std::fs::canonicalize(path) else {
        return vec![];
    };
    let Ok(procs) = std::fs::read_dir("/proc") else {
        return vec![];
    };
    let me = std::process::id();
    let mut out = vec![];
    for p in procs.flatten() {
        let Some(pid) = p.file_name().to_str().and_then(|s| s.parse::<u32>().ok()) else {
            continue;
        };
        if pid == me {
            continue;
        }
        let Ok(fds) = std::fs::read_dir(p.path().join("fd")) else {
            continue;
        };
        if fds
            .flatten()
            .any(|fd| std::fs::read_link(fd.path()).is_ok_and(|l| l == target))
        {
            let name = std::fs::read_to_string(p.path().join("comm"))
                .map_or_else(|_| "another program".into(), |s| s.trim().to_string());
            out.push((pid, name));
        }
    }
    out
}

/// A flag set by Ctrl-C (SIGINT), SIGTERM and SIGHUP (a closed terminal, `kill`, a service
/// manager), for loops that must stop cleanly: flush what they have, send Stop and print a
/// summary. Installed once per process; later calls share it.
pub fn interrupt_flag() -> Arc<AtomicBool> {
    static FLAG: OnceLock<Arc<AtomicBool>> = OnceLock::new();
    FLAG.get_or_init(|| {
        let flag = Arc::new(AtomicBool::new(false));
        let f = flag.clone();
        // If another handler is installed already (library use), Ctrl-C keeps its default
        // behaviour; the loops still end by `--seconds` or when the device closes.
        let _ = ctrlc::set_handler(move || f.store(true, Ordering::SeqCst));
        flag
    })
    .clone()
}

/// The instrument's serial number: its chip's unique ID as 24 upper-case hex digits (the board's
/// USB serial number; all zero on QEMU).
pub fn serial_number(info: &DeviceInfo) -> String {
    info.chip_id.iter().map(|b| format!("{b:02X}")).collect()
}

/// One line about the device: board, firmware, protocol, sample rate, bar lengths, serial number,
/// why it last started (flagged when it reset itself after a crash) and what its clocks run from
/// (flagged when it is not the crystal).
pub fn describe_info(info: &DeviceInfo) -> String {
    let [a, b, c] = info.firmware_version;
    let serial = serial_number(info);
    format!(
        "{:?}, firmware {a}.{b}.{c}, protocol {}, {} Hz, L1 {} mm, L2 {} mm, {}, serial {serial}, reset {:#04x}{}{}, clock {}",
        info.board,
        info.protocol_version,
        info.sample_rate_hz,
        info.calibration.l1_mm,
        info.calibration.l2_mm,
        if info.sampling { "sampling" } else { "idle" },
        info.reset_cause.0,
        if info.reset_cause.crashed() {
            " (it crashed and reset itself)"
        } else {
            ""
        },
        info.unhandled_irq
            .map(|n| format!(" (an interrupt without a handler, IRQ {n}, reset it)"))
            .unwrap_or_default()
            + &(0..2)
                .filter(|&k| info.index_disabled[k])
                .map(|k| format!(", INDEX {} SWITCHED OFF (it interrupted faster than an index can: a noisy or mis-wired line)", k + 1))
                .collect::<String>(),
        match info.clock {
            ClockSource::Crystal => "crystal",
            ClockSource::Internal =>
                "INTERNAL (no usable crystal: time stamps and the sample rate are off by up to 4 %, and USB does not run on it)",
            ClockSource::Emulated => "emulated",
        }
    )
}

/// The serial ports the system knows (USB CDC devices and others; ptys are not listed), each
/// with one line describing it.
pub fn list_ports() -> Result<Vec<(String, String)>> {
    let ports = serialport::available_ports().map_err(|source| Error::PortOpen {
        port: "(listing ports)".into(),
        source,
    })?;
    Ok(ports
        .into_iter()
        .map(|p| {
            let what = match &p.port_type {
                serialport::SerialPortType::UsbPort(u) => format!(
                    "USB {:04x}:{:04x}{}{}",
                    u.vid,
                    u.pid,
                    u.manufacturer
                        .as_deref()
                        .map(|m| format!(" {m}"))
                        .unwrap_or_default(),
                    u.product
                        .as_deref()
                        .map(|m| format!(" {m}"))
                        .unwrap_or_default(),
                ),
                serialport::SerialPortType::PciPort => "PCI".into(),
                serialport::SerialPortType::BluetoothPort => "Bluetooth".into(),
                serialport::SerialPortType::Unknown => "unknown".into(),
            };
            (p.port_name, what)
        })
        .collect())
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use jdbb_core::protocol::{Board, Status, BATCH_LEN};
    use jdbb_core::Calibration;

    fn sample(t_us: u64, k: i64) -> Sample {
        Sample {
            t_us,
            enc1: k,
            enc2: -2 * k,
            d_mm: 100.0 - 1e-4 * k as f64,
            status: Status(Status::SIMULATED),
        }
    }

    /// A batch of `n` samples starting at `seq`, time 1 ms per sample from `t0_us`.
    pub(crate) fn batch(seq: u32, dropped: u32, n: usize, t0_us: u64) -> DeviceMsg {
        let mut samples = heapless::Vec::new();
        for i in 0..n {
            samples
                .push(sample(t0_us + 1000 * i as u64, i64::from(seq) + i as i64))
                .unwrap();
        }
        DeviceMsg::Batch(SampleBatch {
            seq,
            dropped,
            samples,
        })
    }

    pub(crate) fn info() -> DeviceMsg {
        DeviceMsg::Info(DeviceInfo {
            protocol_version: protocol::PROTOCOL_VERSION,
            firmware_version: [0, 1, 0],
            board: Board::QemuNetduinoPlus2,
            sample_rate_hz: 1000,
            sampling: true,
            calibration: Calibration::DEFAULT,
            chip_id: [0; 12],
            reset_cause: protocol::ResetCause(protocol::ResetCause::POWER),
            index: [protocol::IndexStatus {
                reference: protocol::Reference::None,
                armed: true,
                passes: 0,
                last_pass_count: 0,
            }; 2],
            overruns: 0,
            clock: protocol::ClockSource::Emulated,
            calibration_kept: protocol::CalKept::NotSent,
            unhandled_irq: None,
            index_disabled: [false; 2],
        })
    }

    pub(crate) fn frame(msg: &DeviceMsg) -> Vec<u8> {
        let mut buf = [0u8; MAX_FRAME_LEN];
        protocol::encode(msg, &mut buf).unwrap().to_vec()
    }

    /// Frames for consecutive full batches covering seq `from..from + 16·n`, 1 ms apart.
    pub(crate) fn run(from: u32, n: usize) -> Vec<u8> {
        (0..n)
            .flat_map(|k| {
                let seq = from + (k * BATCH_LEN) as u32;
                frame(&batch(seq, 0, BATCH_LEN, 1000 * u64::from(seq)))
            })
            .collect()
    }

    /// Everything a stream decodes from `bytes` read `chunk` bytes at a time.
    fn decode(bytes: &[u8], chunk: usize) -> (Vec<SeqSample>, Stats) {
        let mut s = Stream::new(bytes, "test");
        let mut out = Vec::new();
        for part in bytes.chunks(chunk) {
            s.feed(part, |b| out.extend_from_slice(b));
        }
        (out, *s.stats())
    }

    fn seqs(samples: &[SeqSample]) -> Vec<u64> {
        samples.iter().map(|s| s.seq).collect()
    }

    #[test]
    fn the_device_line_says_what_the_clocks_run_from() {
        let DeviceMsg::Info(mut i) = info() else {
            unreachable!()
        };
        assert!(describe_info(&i).ends_with(", clock emulated"));
        i.clock = ClockSource::Crystal;
        assert!(describe_info(&i).ends_with(", clock crystal"));
        // A board whose crystal did not start runs on the internal oscillator: flagged, with
        // what it costs.
        i.clock = ClockSource::Internal;
        let line = describe_info(&i);
        assert!(line.contains("clock INTERNAL"), "{line}");
        assert!(line.contains("off by up to 4 %"), "{line}");
    }

    #[test]
    fn clean_stream_in_any_split_loses_nothing() {
        let bytes = run(0, 10);
        for chunk in [1, 2, 7, 39, 1000, bytes.len()] {
            let (got, st) = decode(&bytes, chunk);
            assert_eq!(seqs(&got), (0..160).collect::<Vec<_>>(), "chunk {chunk}");
            assert_eq!(st.samples, 160);
            assert_eq!(st.frames_ok, 10);
            assert_eq!((st.lost, st.resets, st.corrupt.total()), (0, 0, 0));
            assert_eq!(st.bytes, bytes.len() as u64);
            // The samples are the ones encoded, bit for bit.
            for s in &got {
                assert_eq!(s.sample, sample(1000 * s.seq, s.seq as i64));
            }
        }
    }

    #[test]
    fn poll_reads_to_the_end_of_an_in_memory_source() {
        let bytes = run(32, 300); // more than one READ_CHUNK
        assert!(bytes.len() > READ_CHUNK);
        let mut s = Stream::new(&bytes[..], "mem");
        let mut n = 0;
        let mut polls = 0;
        loop {
            polls += 1;
            match s.poll(|b| n += b.len()).unwrap() {
                Poll::Closed => break,
                Poll::Data(_) => {}
                Poll::Idle => panic!("a slice never times out"),
            }
        }
        assert!(polls > 2);
        assert_eq!(n, 300 * BATCH_LEN);
        assert_eq!(s.stats().samples, 4800);
        assert_eq!(s.last_sample().unwrap().seq, 32 + 4800 - 1);
        assert_eq!(s.poll(|_| {}).unwrap(), Poll::Closed);
    }

    #[test]
    fn gaps_in_sequence_count_as_lost() {
        // Batches 0, 16, [32 and 48 missing], 64, then a short batch of 5 at 80, then 100 (15
        // missing: 85..100).
        let mut bytes = run(0, 2);
        bytes.extend(run(64, 1));
        bytes.extend(frame(&batch(80, 0, 5, 80_000)));
        bytes.extend(frame(&batch(100, 0, 16, 100_000)));
        let (got, st) = decode(&bytes, 64);
        assert_eq!(st.lost, 32 + 15);
        assert_eq!(st.samples, 16 * 3 + 5 + 16);
        assert_eq!(st.resets, 0);
        let mut want: Vec<u64> = (0..32).chain(64..85).collect();
        want.extend(100..116);
        assert_eq!(seqs(&got), want);
    }

    #[test]
    fn device_dropped_is_tracked_and_summed_over_restarts() {
        let mut bytes = frame(&batch(0, 0, 16, 0));
        // The device dropped 4 samples (queue full): they appear as a gap and in `dropped`.
        bytes.extend(frame(&batch(20, 4, 16, 20_000)));
        bytes.extend(frame(&batch(36, 4, 16, 36_000)));
        // Device restarts (unprompted), then drops 3 in its new session.
        bytes.extend(frame(&batch(0, 0, 16, 0)));
        bytes.extend(frame(&batch(19, 3, 16, 19_000)));
        let (_, st) = decode(&bytes, 50);
        assert_eq!(st.device_dropped, 7);
        assert_eq!(st.lost, 7);
        assert_eq!(st.resets, 1);
    }

    #[test]
    fn corrupt_frames_are_counted_by_kind_and_skipped() {
        let good: Vec<Vec<u8>> = (0..6).map(|k| run(16 * k, 1)).collect();
        let mut bytes = Vec::new();
        bytes.extend(&good[0]); // batch 0 intact
                                // Batch 16 with one payload byte changed (to a nonzero value, so the frame keeps its
                                // length and COBS structure... unless it hits a COBS code byte, then it is a COBS error;
                                // byte 20 is a data byte for this frame, checked by the counts below): the CRC fails.
        let mut crc_bad = good[1].clone();
        crc_bad[20] = if crc_bad[20] == 0x5a { 0x5b } else { 0x5a };
        bytes.extend(&crc_bad);
        // Batch 32 with its first COBS code byte pointing past the frame end: invalid COBS.
        let mut cobs_bad = good[2].clone();
        cobs_bad[0] = 0xfe;
        bytes.extend(&cobs_bad);
        bytes.extend(&good[3]); // batch 48 intact
                                // Line noise without a delimiter for longer than a frame, then a delimiter.
        bytes.extend(std::iter::repeat_n(0x77u8, 2 * MAX_FRAME_LEN));
        bytes.push(0);
        bytes.extend(&good[4]); // batches 64, 80 intact
        bytes.extend(&good[5]);
        // A frame with a valid CRC that is no known message.
        let mut unknown = [0u8; 64];
        let f = protocol::encode(&(200u8, 7u32), &mut unknown)
            .unwrap()
            .to_vec();
        bytes.extend(f);
        for chunk in [1, 13, 4096] {
            let (got, st) = decode(&bytes, chunk);
            assert_eq!(
                st.corrupt,
                CorruptFrames {
                    crc: 1,
                    cobs: 1,
                    overflow: 1,
                    payload: 1
                },
                "chunk {chunk}"
            );
            assert_eq!(st.frames_ok, 4);
            assert_eq!(st.samples, 64);
            assert_eq!(st.lost, 32); // batches 16 and 32
            assert_eq!(st.resets, 0);
            let want: Vec<u64> = (0..16).chain(48..96).collect();
            assert_eq!(seqs(&got), want);
        }
    }

    #[test]
    fn garbage_before_and_between_frames_is_survived() {
        // Leading garbage (a receiver joining mid-frame), a truncated frame (the device reset
        // while sending), then clean frames.
        let mut bytes = vec![0x13, 0x37, 0xff, 0x01];
        let f = frame(&batch(0, 0, 16, 0));
        bytes.extend_from_slice(&f[..f.len() / 2]);
        bytes.extend(run(16, 3));
        let (got, st) = decode(&bytes, 5);
        // The leading garbage and the truncated frame have no delimiter of their own: they run
        // into the next frame (batch 16) up to its 0x00, and the three make one bad frame: the
        // first one, so it is the cut of opening mid-stream, not a corruption.
        assert_eq!((st.partial, st.corrupt.total()), (1, 0));
        assert_eq!(seqs(&got), (32..64).collect::<Vec<_>>());
        assert_eq!(st.lost, 0); // joined at 32: nothing before counts as lost
                                // The same bad frame after a good one is corrupt.
        let mut later = run(0, 1);
        later.extend(&bytes);
        let (_, st) = decode(&later, 5);
        assert_eq!((st.partial, st.corrupt.total()), (0, 1));
    }

    #[test]
    fn reset_detected_by_sequence_going_back() {
        let mut bytes = run(0, 4); // 0..64
        bytes.extend(run(32, 2)); // restarted and already at 32: 0..32 of the new session lost
        let (got, st) = decode(&bytes, 100);
        assert_eq!(st.resets, 1);
        assert_eq!(st.lost, 32);
        assert_eq!(st.samples, 96);
        assert_eq!(got[64].seq, 32);
    }

    #[test]
    fn reset_detected_by_clock_going_back_even_if_sequence_continues() {
        let mut bytes = frame(&batch(0, 0, 16, 1_000_000));
        // Same seq as expected next, but time restarted: a fresh session that happens to line up.
        bytes.extend(frame(&batch(16, 0, 16, 0)));
        let (_, st) = decode(&bytes, 100);
        assert_eq!(st.resets, 1);
        assert_eq!(st.lost, 16);
    }

    #[test]
    fn unprompted_info_is_a_reset_counted_once() {
        // Start-up info before any sample: not a reset.
        let mut all = frame(&info());
        all.extend(run(0, 3));
        // The device rebooted (now at 2 kHz) and announces itself unprompted...
        let DeviceMsg::Info(mut rebooted) = info() else {
            unreachable!()
        };
        rebooted.sample_rate_hz = 2000;
        all.extend(frame(&DeviceMsg::Info(rebooted)));
        // ...and its sequence restarts: the same reset, not a second one.
        all.extend(run(0, 2));
        let mut s = Stream::new(&all[..], "x");
        let mut got = Vec::new();
        while s.poll(|b| got.extend_from_slice(b)).unwrap() != Poll::Closed {}
        let st = s.stats();
        assert_eq!((st.resets, st.lost, st.frames_ok), (1, 0, 7));
        assert_eq!(got.len(), 80);
        assert_eq!(
            s.info().unwrap().sample_rate_hz,
            2000,
            "the latest info is kept"
        );
    }

    /// A port for tests: reads `input` (then EOF), keeps what is written.
    pub(crate) struct Duplex {
        pub(crate) input: io::Cursor<Vec<u8>>,
        pub(crate) sent: Vec<u8>,
    }

    impl Duplex {
        pub(crate) fn new(input: Vec<u8>) -> Self {
            Duplex {
                input: io::Cursor::new(input),
                sent: Vec::new(),
            }
        }
    }

    impl Read for Duplex {
        fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
            self.input.read(buf)
        }
    }

    impl Write for Duplex {
        fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
            self.sent.extend_from_slice(buf);
            Ok(buf.len())
        }
        fn flush(&mut self) -> io::Result<()> {
            Ok(())
        }
    }

    #[test]
    fn start_after_joining_a_running_stream_is_not_a_reset() {
        // Open, send Start, but the first batches still come from the session that was running.
        let mut s = Stream::new(Duplex::new(Vec::new()), "mem");
        s.send(&Command::Start).unwrap();
        let mut bytes = Vec::new();
        bytes.extend(frame(&batch(5000, 0, 4, 5_000_000)));
        bytes.extend(frame(&batch(5004, 0, 4, 5_004_000)));
        bytes.extend(frame(&info())); // the answer to Start
        bytes.extend(frame(&batch(0, 0, 4, 0)));
        bytes.extend(frame(&batch(4, 0, 4, 4000)));
        let mut got = Vec::new();
        s.feed(&bytes, |b| got.extend_from_slice(b));
        let st = s.stats();
        assert_eq!((st.resets, st.lost, st.samples), (0, 0, 8));
        assert_eq!(st.before_start, 8);
        assert_eq!(seqs(&got), (0..8).collect::<Vec<_>>());
        // ...and a genuine reset later is still seen.
        s.feed(&frame(&batch(0, 0, 4, 0)), |_| {});
        assert_eq!(s.stats().resets, 1);
    }

    #[test]
    fn samples_before_the_acknowledged_start_are_discarded_even_at_small_seq() {
        // The device had just started a run (seq 0, 16, ...) when our GetInfo and Start arrived:
        // its batches before the answer to Start look like a fresh run but are not ours.
        let mut s = Stream::new(Duplex::new(Vec::new()), "mem");
        s.send(&Command::GetInfo).unwrap();
        s.send(&Command::Start).unwrap();
        assert!(!s.run_begun());
        let mut bytes = run(0, 1);
        bytes.extend(frame(&info())); // answer to GetInfo
        bytes.extend(run(16, 1));
        let mut got = Vec::new();
        s.feed(&bytes, |b| got.extend_from_slice(b));
        assert!(got.is_empty());
        assert!(!s.run_begun());
        // The answer to Start, then the new run.
        let mut bytes = frame(&info());
        bytes.extend(run(0, 3));
        s.feed(&bytes, |b| got.extend_from_slice(b));
        assert!(s.run_begun());
        assert_eq!(seqs(&got), (0..48).collect::<Vec<_>>());
        let st = s.stats();
        assert_eq!(
            (st.before_start, st.samples, st.resets, st.lost),
            (32, 48, 0, 0)
        );
        assert!(s.check_start().is_ok());
    }

    #[test]
    fn a_refused_or_unanswered_start_is_an_error() {
        let mut s = Stream::new(Duplex::new(Vec::new()), "mem");
        s.send(&Command::Start).unwrap();
        assert!(s.check_start().is_ok(), "not overdue yet");
        s.feed(
            &frame(&DeviceMsg::Rejected(CommandError::Malformed)),
            |_| {},
        );
        let e = s.check_start().unwrap_err().to_string();
        assert!(e.contains("refused Start"), "{e}");
        // Unanswered: overdue after START_ACK_TIMEOUT.
        let mut s = Stream::new(Duplex::new(Vec::new()), "mem");
        s.send(&Command::Start).unwrap();
        s.tracker.gate = Gate::AwaitAck {
            reply: 0,
            sent: Instant::now() - START_ACK_TIMEOUT - Duration::from_millis(1),
        };
        let mut n = 0;
        s.feed(&run(0, 2), |b| n += b.len());
        assert_eq!(n, 0);
        let e = s.check_start().unwrap_err().to_string();
        assert!(e.contains("did not acknowledge Start"), "{e}");
    }

    #[test]
    fn one_run_mode_delivers_nothing_after_a_restart() {
        for (cause, restart) in [
            ("seq", run(0, 1)),
            ("clock", frame(&batch(64, 0, 16, 0))),
            ("info", {
                let mut b = frame(&info());
                b.extend(run(0, 1));
                b
            }),
        ] {
            let mut s = Stream::new(Duplex::new(Vec::new()), "mem");
            s.set_one_run(true);
            let mut bytes = run(0, 4);
            bytes.extend(&restart);
            bytes.extend(run(16, 2));
            let mut got = Vec::new();
            s.feed(&bytes, |b| got.extend_from_slice(b));
            assert_eq!(seqs(&got), (0..64).collect::<Vec<_>>(), "{cause}");
            let r = s.run_ended().expect(cause);
            assert_eq!(r.last.unwrap().seq, 63, "{cause}");
            let msg = r.to_string();
            assert!(msg.contains("after seq 63, t_us 63000"), "{cause}: {msg}");
            assert_eq!(s.stats().resets, 1, "{cause}");
        }
    }

    #[test]
    fn restart_requested_with_start_is_not_a_reset() {
        let mut sink = std::io::Cursor::new(Vec::new());
        let mut s = Stream::new(&mut sink, "x");
        s.feed(&run(0, 3), |_| {});
        s.send(&Command::Start).unwrap();
        // The device replies with its info and restarts its sequence.
        s.feed(&frame(&info()), |_| {});
        s.feed(&run(0, 3), |_| {});
        assert_eq!(s.stats().resets, 0);
        assert_eq!(s.stats().samples, 96);
        assert_eq!(s.stats().lost, 0);
        // A later unrequested restart is one.
        s.feed(&run(0, 1), |_| {});
        assert_eq!(s.stats().resets, 1);
        // The command went out as one frame that decodes back to Start.
        let sent = sink.into_inner();
        let mut d = protocol::Decoder::<MAX_FRAME_LEN>::new();
        let mut cmds = Vec::new();
        d.feed::<Command>(&sent, |c| cmds.push(c));
        assert_eq!(cmds, vec![Ok(Command::Start)]);
    }

    #[test]
    fn sequence_extends_across_u32_wrap() {
        let start = u32::MAX - 23; // batches at MAX-23, MAX-7 (wraps inside), 8
        let mut bytes = Vec::new();
        for k in 0..3u32 {
            let seq = start.wrapping_add(16 * k);
            bytes.extend(frame(&batch(seq, 0, 16, 16_000 * u64::from(k))));
        }
        let (got, st) = decode(&bytes, 100);
        assert_eq!((st.resets, st.lost), (0, 0));
        let first = u64::from(start);
        assert_eq!(seqs(&got), (first..first + 48).collect::<Vec<_>>());
    }

    #[test]
    fn pong_and_rejected_are_recorded() {
        let mut bytes = frame(&DeviceMsg::Pong(42));
        bytes.extend(frame(&DeviceMsg::Rejected(
            CommandError::SampleRateOutOfRange,
        )));
        let mut s = Stream::new(&bytes[..], "x");
        while s.poll(|_| {}).unwrap() != Poll::Closed {}
        assert_eq!(s.last_pong(), Some(42));
        assert_eq!(s.last_rejected(), Some(CommandError::SampleRateOutOfRange));
        assert_eq!((s.stats().pongs, s.stats().rejected), (1, 1));
    }

    #[test]
    fn read_error_is_reported_after_delivering_what_was_decoded() {
        /// Gives its bytes, then fails like an unplugged USB device.
        struct Unplugged(Vec<u8>, bool);
        impl Read for Unplugged {
            fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
                if self.1 {
                    return Err(io::Error::new(io::ErrorKind::BrokenPipe, "EPIPE"));
                }
                self.1 = true;
                buf[..self.0.len()].copy_from_slice(&self.0);
                Ok(self.0.len())
            }
        }
        let mut bytes = run(0, 2);
        bytes.extend_from_slice(&run(32, 1)[..10]); // cut mid-frame
        let mut s = Stream::new(Unplugged(bytes, false), "/dev/ttyACM0");
        let mut n = 0;
        assert!(matches!(s.poll(|b| n += b.len()), Ok(Poll::Data(_))));
        let e = s.poll(|b| n += b.len()).unwrap_err();
        assert!(e.to_string().contains("/dev/ttyACM0"), "{e}");
        assert!(e.to_string().contains("unplugged"), "{e}");
        assert_eq!(n, 32);
        assert_eq!(s.pending_bytes(), 10);
        assert_eq!(s.poll(|_| {}).unwrap(), Poll::Closed);
    }

    #[test]
    fn collect_stops_at_n_or_at_the_end() {
        let bytes = run(0, 10);
        let mut s = Stream::new(&bytes[..], "x");
        let got = s.collect(40, Duration::from_secs(5)).unwrap();
        // Whole reads: at least 40, and everything decoded is returned.
        assert!(got.len() >= 40);
        let rest = s.collect(1000, Duration::from_secs(5)).unwrap();
        assert_eq!(got.len() + rest.len(), 160);
    }

    #[test]
    fn ports_that_are_not_devices_are_refused_clearly() {
        let dir = tempfile::tempdir().unwrap();
        let cases = [
            (
                dir.path().join("nope").display().to_string(),
                "no such port",
            ),
            (dir.path().display().to_string(), "directory"),
            ("/etc/passwd".to_string(), "regular file"),
        ];
        for (path, want) in cases {
            let Err(e) = open_port(&path) else {
                panic!("{path} opened as a port")
            };
            let msg = e.to_string();
            assert!(msg.contains(&path) && msg.contains(want), "{msg}");
        }
    }
}
