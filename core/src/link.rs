//! The device's side of the link to the host, free of hardware: what the writer task does when
//! the host does not read, and how much of the message queue sample batches may take.
//!
//! - [`Presence`]: a host that has stopped reading (program closed, USB not configured, cable
//!   out) is detected by the writer's timeout. From then on messages are discarded at once (their
//!   samples counted as dropped) and what the link still buffers is thrown away, instead of
//!   delivering a stale kilobyte and a queue of old batches when a host comes back. The host is
//!   back when it sends a command, when the link comes up (USB configured), or when two probe
//!   bytes (0x00, a frame delimiter the decoder skips) have left the link's buffer one after the
//!   other — the second can only leave once the host has read the packet before it.
//! - [`BatchQuota`]: sample batches may take at most `limit` places of the queue, so replies to
//!   commands always find one.
//! - [`Outgoing`]: a queued message with the sampling run it belongs to, so that a drop of a
//!   previous run's batch is not counted in the current run (`Sampler::count_dropped_in`).

use core::sync::atomic::{AtomicUsize, Ordering};

use crate::protocol::DeviceMsg;

/// A message on its way to the host, with the run (`Sampler::run`) it was produced in.
#[derive(Debug, Clone, PartialEq)]
pub struct Outgoing {
    /// The sampling run of a batch (`Sampler::run` when it was sealed).
    pub run: u32,
    /// The message.
    pub msg: DeviceMsg,
}

impl Outgoing {
    /// Samples the message carries (0 for anything but a batch).
    pub fn samples(&self) -> u32 {
        match &self.msg {
            DeviceMsg::Batch(b) => b.samples.len() as u32,
            _ => 0,
        }
    }

    /// Whether the message is a sample batch (which holds a place of the [`BatchQuota`]).
    pub fn is_batch(&self) -> bool {
        matches!(self.msg, DeviceMsg::Batch(_))
    }
}

/// What the writer does next while the host is absent (see [`Presence::probe_step`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ProbeStep {
    /// Write one 0x00 byte to the link, then call [`Presence::probe_sent`] if it was taken.
    Send,
    /// The last probe is still in the link's buffer: nobody reads.
    Wait,
    /// A host read the link: it is present again; write normally.
    HostBack,
}

/// Whether a host reads the link, judged by the writer (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Presence {
    present: bool,
    probes: u8,
}

impl Presence {
    /// A link whose host is present (`true`, e.g. a UART) or not yet (`false`, e.g. USB before
    /// the host configured the device).
    pub const fn new(present: bool) -> Self {
        Presence { present, probes: 0 }
    }

    /// Whether messages are to be written (else discarded and counted).
    pub fn is_present(&self) -> bool {
        self.present
    }

    /// The writer waited the link timeout for a frame without any progress. Returns true if the
    /// host was present until now: the caller then discards what the link still buffers.
    pub fn on_timeout(&mut self) -> bool {
        let was = self.present;
        self.present = false;
        self.probes = 0;
        was
    }

    /// The host sent something, or the link came up: it is present.
    pub fn on_host_activity(&mut self) {
        self.present = true;
        self.probes = 0;
    }

    /// While absent: what to do, given whether the link's transmit buffer is empty (`drained`).
    pub fn probe_step(&mut self, drained: bool) -> ProbeStep {
        if self.present {
            ProbeStep::HostBack
        } else if !drained {
            ProbeStep::Wait
        } else if self.probes >= 2 {
            self.on_host_activity();
            ProbeStep::HostBack
        } else {
            ProbeStep::Send
        }
    }

    /// The probe byte asked for by [`ProbeStep::Send`] was taken by the link.
    pub fn probe_sent(&mut self) {
        self.probes = self.probes.saturating_add(1);
    }
}

/// Places of the message queue that sample batches hold (shared by the sample task, which takes
/// one per batch, and the writer, which gives it back when it receives the batch).
#[derive(Debug)]
pub struct BatchQuota {
    queued: AtomicUsize,
    limit: usize,
}

impl BatchQuota {
    /// A quota of `limit` batches.
    pub const fn new(limit: usize) -> Self {
        BatchQuota {
            queued: AtomicUsize::new(0),
            limit,
        }
    }

    /// Take a place for one batch; false if batches already hold `limit` (drop the batch).
    pub fn try_take(&self) -> bool {
        self.queued
            .fetch_update(Ordering::AcqRel, Ordering::Acquire, |n| {
                (n < self.limit).then_some(n + 1)
            })
            .is_ok()
    }

    /// Give back the place of a batch that left the queue (or was never queued after all).
    pub fn release(&self) {
        let _ = self
            .queued
            .fetch_update(Ordering::AcqRel, Ordering::Acquire, |n| n.checked_sub(1));
    }

    /// Batches holding a place now.
    pub fn queued(&self) -> usize {
        self.queued.load(Ordering::Acquire)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A model of the USB CDC transmit path: the class's software buffer, then one packet in the
    /// endpoint that leaves only when the host reads. `write` takes what fits the buffer, moves a
    /// packet into a free endpoint at once; `host_reads` frees the endpoint.
    struct Link {
        buf: std::vec::Vec<u8>,
        cap: usize,
        endpoint: Option<std::vec::Vec<u8>>,
        received: std::vec::Vec<u8>,
    }

    impl Link {
        fn new(cap: usize) -> Self {
            Link {
                buf: std::vec::Vec::new(),
                cap,
                endpoint: None,
                received: std::vec::Vec::new(),
            }
        }
        fn pump(&mut self) {
            if self.endpoint.is_none() && !self.buf.is_empty() {
                let n = self.buf.len().min(64);
                self.endpoint = Some(self.buf.drain(..n).collect());
            }
        }
        fn write(&mut self, bytes: &[u8]) -> usize {
            let n = bytes.len().min(self.cap - self.buf.len());
            self.buf.extend_from_slice(&bytes[..n]);
            self.pump();
            n
        }
        fn drained(&self) -> bool {
            self.buf.is_empty()
        }
        fn discard(&mut self) {
            self.buf.clear();
        }
        fn host_reads(&mut self) {
            if let Some(p) = self.endpoint.take() {
                self.received.extend(p);
            }
            self.pump();
        }
    }

    /// Run the writer's absent-host loop `rounds` times; returns the round at which the host was
    /// seen back.
    fn probe_rounds(p: &mut Presence, link: &mut Link, rounds: usize) -> Option<usize> {
        for r in 0..rounds {
            match p.probe_step(link.drained()) {
                ProbeStep::HostBack => return Some(r),
                ProbeStep::Wait => {}
                ProbeStep::Send => {
                    if link.write(&[0]) == 1 {
                        p.probe_sent();
                    }
                }
            }
        }
        None
    }

    #[test]
    fn absent_host_is_not_mistaken_for_present_and_is_found_when_it_reads() {
        let mut link = Link::new(1024);
        let mut p = Presence::new(true);
        // The host stops reading: a frame fills the endpoint and the buffer, the writer times out.
        assert_eq!(link.write(&[7u8; 1000]), 1000);
        assert!(p.on_timeout(), "first timeout changes the state");
        assert!(!p.on_timeout(), "later ones do not");
        link.discard();
        // No reader: probes never report the host back, however long we try.
        assert_eq!(probe_rounds(&mut p, &mut link, 100), None);
        assert!(!p.is_present());
        // The host reads: first the stale packet (64 B), then the probes; it is found back.
        link.host_reads();
        assert_eq!(
            probe_rounds(&mut p, &mut link, 10),
            None,
            "one packet read is not enough"
        );
        link.host_reads();
        assert!(probe_rounds(&mut p, &mut link, 10).is_some());
        assert!(p.is_present());
        // What the host got after its absence: one stale packet and one probe byte, no more.
        assert_eq!(link.received.len(), 64 + 1);
        assert!(link.received[64..].iter().all(|&b| b == 0));
    }

    #[test]
    fn free_endpoint_needs_a_second_probe() {
        // The endpoint is empty when the host goes away (e.g. USB not yet configured and nothing
        // written): the first probe goes straight into the endpoint, which proves nothing.
        let mut link = Link::new(1024);
        let mut p = Presence::new(false);
        assert_eq!(probe_rounds(&mut p, &mut link, 50), None);
        link.host_reads();
        assert!(probe_rounds(&mut p, &mut link, 3).is_some());
    }

    #[test]
    fn a_command_brings_the_host_back_at_once() {
        let mut p = Presence::new(true);
        p.on_timeout();
        p.on_host_activity();
        assert!(p.is_present());
        assert_eq!(p.probe_step(false), ProbeStep::HostBack);
    }

    #[test]
    fn power_up_greeting_fits_one_full_speed_usb_packet() {
        // The board greets when the host configures it; a program that opens the port later
        // still gets the greeting if it sits whole in the endpoint's one 64-byte packet.
        use crate::protocol::*;
        let status = crate::quadrature::Encoder::<32>::new(0).index_status();
        let info = DeviceInfo {
            protocol_version: PROTOCOL_VERSION,
            firmware_version: [255; 3],
            board: Board::BlackPillF411,
            sample_rate_hz: 1000,
            sampling: true,
            calibration: crate::Calibration::DEFAULT,
            chip_id: [0xff; 12],
            reset_cause: ResetCause(0xff),
            index: [status; 2],
            overruns: 0,
            clock: ClockSource::Crystal,
            calibration_kept: crate::protocol::CalKept::NotSent,
            unhandled_irq: None,
            index_disabled: [false; 2],
        };
        let hello = DeviceMsg::Hello(Hello::of(&info));
        let mut buf = [0u8; MAX_FRAME_LEN];
        let n = encode(&hello, &mut buf).unwrap().len();
        assert!(n <= 64, "greeting frame is {n} bytes");
    }

    #[test]
    fn quota_leaves_room_for_replies() {
        let q = BatchQuota::new(3);
        assert!(q.try_take() && q.try_take() && q.try_take());
        assert!(!q.try_take(), "a fourth batch is refused");
        assert_eq!(q.queued(), 3);
        q.release();
        assert!(q.try_take());
        for _ in 0..10 {
            q.release();
        }
        assert_eq!(q.queued(), 0, "never below zero");
    }
}
