//! The QEMU build of the firmware, driven through the host's `jdbb::stream` over the pty: what
//! issue 11 changed in the command handling, end to end.
//!
//! - `SetSampleRate` while sampling (no `Start` after it) takes effect at a period boundary: the
//!   sequence stays contiguous, nothing is dropped, and the time stamps step by exactly the old
//!   period, then by exactly the new one — the sample clock is not restarted mid-period.
//! - `DeviceInfo` (protocol 2) reports the index state, overruns and reset cause, and `ArmIndex`
//!   re-arms both encoders' index.
mod common;

use common::collect_run;
use std::time::{Duration, Instant};

use jdbb::link::stream::{Poll, Stream};
use jdbb_core::protocol::{Command, Reference, PROTOCOL_VERSION};
use jdbb_tests::{qemu_available, qemu_elf, Qemu};

#[test]
fn rate_change_while_sampling_keeps_time_continuous_and_arm_index_rearms() {
    let elf = qemu_elf("jdbb-firmware");
    if !qemu_available(&elf) {
        return;
    }
    let (_qemu, pty) = Qemu::start_with_pty(&elf);
    let mut stream = Stream::open(pty.to_str().unwrap()).expect("open QEMU pty");
    // Until QEMU notices the pty was opened, what the firmware writes is dropped.
    assert!(
        stream.handshake(Duration::from_secs(30)).unwrap(),
        "the firmware never answered a ping"
    );
    stream.send(&Command::SetSampleRate(1_000)).unwrap();
    stream.send(&Command::Start).unwrap();
    let mut got = collect_run(&mut stream, 1_000, Duration::from_secs(60));
    // Now 2 kHz, without a Start: the running sample clock must carry on seamlessly.
    stream.send(&Command::SetSampleRate(2_000)).unwrap();
    got.extend(
        stream
            .collect(3_000, Duration::from_secs(60))
            .expect("read from the QEMU pty"),
    );
    let stats = *stream.stats();
    assert!(got.len() >= 4_000, "only {} samples: {stats}", got.len());
    assert_eq!(stats.lost, 0, "{stats}");
    assert_eq!(stats.device_dropped, 0, "{stats}");
    assert_eq!(stats.resets, 0, "{stats}");
    assert_eq!(stream.info().map(|i| i.sample_rate_hz), Some(2_000));
    let steps: Vec<u64> = got
        .windows(2)
        .map(|w| {
            assert_eq!(w[1].seq, w[0].seq + 1, "sequence gap");
            w[1].sample.t_us - w[0].sample.t_us
        })
        .collect();
    let switch = steps
        .iter()
        .position(|&d| d != 1_000)
        .expect("the rate never changed");
    assert!(switch >= 900, "changed too early, at step {switch}");
    assert!(
        steps[switch..].iter().all(|&d| d == 500),
        "after the change every step is 500 µs: {:?}",
        &steps[switch.saturating_sub(2)..(switch + 5).min(steps.len())]
    );
    println!(
        "rate change while sampling: {} samples, 1 kHz → 2 kHz at seq {}, steps exactly 1000 then 500 µs",
        got.len(),
        got[switch + 1].seq
    );

    // Protocol 2's DeviceInfo, and ArmIndex.
    let info = *stream.info().expect("Info replies");
    assert_eq!(info.protocol_version, PROTOCOL_VERSION);
    assert_eq!(info.overruns, 0, "no overrun under -icount");
    assert_eq!(info.chip_id, [0; 12], "QEMU has no unique ID");
    for st in info.index {
        // The simulated encoders are referenced at power-up, where their index is.
        assert_eq!(
            (st.reference, st.armed),
            (Reference::Index, false),
            "{st:?}"
        );
    }
    stream.send(&Command::ArmIndex).unwrap();
    let t0 = Instant::now();
    while !stream
        .info()
        .is_some_and(|i| i.index.iter().all(|s| s.armed))
    {
        assert!(
            t0.elapsed() < Duration::from_secs(30),
            "no Info after ArmIndex"
        );
        if stream.poll(|_| {}).unwrap() == Poll::Closed {
            panic!("QEMU closed the pty");
        }
    }
    let info = stream.info().unwrap();
    assert!(info.index.iter().all(|s| s.reference == Reference::Index));
}
