//! What the QEMU streaming tests share (they use the host's decoder, which the library of this
//! crate must not: its simulators are written apart from the host).
use std::time::{Duration, Instant};

use jdbb::link::stream::{SeqSample, Stream};

/// Collect at least `n` samples of the run that the last `Start` began: samples that were still in
/// flight from the run before it (up to the sequence's restart at 0) are dropped. Gives up after
/// `timeout` with what it has.
pub fn collect_run<P: std::io::Read>(
    stream: &mut Stream<P>,
    n: usize,
    timeout: Duration,
) -> Vec<SeqSample> {
    let t0 = Instant::now();
    let mut got: Vec<SeqSample> = Vec::new();
    while got.len() < n && t0.elapsed() < timeout {
        let more = stream
            .collect(n - got.len(), timeout.saturating_sub(t0.elapsed()))
            .expect("read from the QEMU pty");
        got.extend(more);
        if let Some(k) = got.iter().rposition(|s| s.seq == 0) {
            got.drain(..k);
        }
    }
    got
}
