//! Host decoding throughput: a large in-memory stream of `SampleBatch` frames through exactly the
//! path `jdbb record` uses — `Stream::poll` (16 KiB reads → COBS → CRC-32C → postcard → sequence
//! and loss accounting → batch callback) — first without output, then with the CSV formatting of
//! `record::write_csv_lines` (into memory; the file write is left out).
//!
//! Run: `cargo bench -p jdbb --bench decode` (release profile). Goal: ≥ 5 million samples/s.
use std::hint::black_box;
use std::time::Instant;

use jdbb::link::record::write_csv_lines;
use jdbb::link::stream::{Poll, Stream};
use jdbb_core::geometry::{counts_for_distance, distance_mm};
use jdbb_core::protocol::{self, DeviceMsg, Sample, SampleBatch, Status, BATCH_LEN, MAX_FRAME_LEN};
use jdbb_core::Calibration;

/// Samples in the stream: 100 s of a 10 kHz circular test.
const SAMPLES: usize = 1_000_000;

/// Frames of a simulated circular test at 10 kHz: D wobbles by ±5 µm around 99.9 mm while the
/// deflection direction turns, so counts and D vary like real data (varint lengths included).
fn stream_bytes(cal: &Calibration) -> Vec<u8> {
    let mut bytes = Vec::with_capacity(SAMPLES * 40);
    let mut buf = [0u8; MAX_FRAME_LEN];
    for b in 0..SAMPLES / BATCH_LEN {
        let mut samples = heapless::Vec::new();
        for i in 0..BATCH_LEN {
            let k = b * BATCH_LEN + i;
            let psi = k as f64 * 1e-4 * std::f64::consts::TAU / 10.0; // one turn per 10 s
            let d = 99.9 + 0.005 * (3.0 * psi).sin();
            let (enc1, enc2) = counts_for_distance(cal, d, psi).expect("D in range");
            samples
                .push(Sample {
                    t_us: 100 * k as u64,
                    enc1,
                    enc2,
                    d_mm: distance_mm(cal, enc1, enc2),
                    status: Status(Status::ENC1_REFERENCED | Status::ENC2_REFERENCED),
                })
                .unwrap();
        }
        let msg = DeviceMsg::Batch(SampleBatch {
            seq: (b * BATCH_LEN) as u32,
            dropped: 0,
            samples,
        });
        bytes.extend_from_slice(protocol::encode(&msg, &mut buf).unwrap());
    }
    bytes
}

/// Decode everything once; `csv` adds the CSV formatting. Returns (samples, seconds).
fn run(bytes: &[u8], csv: bool) -> (u64, f64) {
    let t0 = Instant::now();
    let mut stream = Stream::new(bytes, "bench");
    let mut lines = Vec::with_capacity(1 << 20);
    let mut sum = 0.0;
    loop {
        let p = stream
            .poll(|batch| {
                if csv {
                    write_csv_lines(&mut lines, batch);
                } else {
                    sum += batch.iter().map(|s| s.sample.d_mm).sum::<f64>();
                }
            })
            .unwrap();
        black_box(&lines);
        lines.clear();
        if p == Poll::Closed {
            break;
        }
    }
    black_box(sum);
    let st = stream.stats();
    assert_eq!(st.samples as usize, SAMPLES);
    assert_eq!((st.lost, st.corrupt.total(), st.resets), (0, 0, 0));
    (st.samples, t0.elapsed().as_secs_f64())
}

fn main() {
    let cal = Calibration::DEFAULT;
    let bytes = stream_bytes(&cal);
    println!(
        "stream: {} samples in {} frames, {:.1} MB ({:.1} bytes/sample)",
        SAMPLES,
        SAMPLES / BATCH_LEN,
        bytes.len() as f64 / 1e6,
        bytes.len() as f64 / SAMPLES as f64
    );
    for (name, csv) in [
        ("decode (Stream::poll)", false),
        ("decode + CSV lines", true),
    ] {
        let _ = run(&bytes, csv); // warm-up
        let best = (0..5)
            .map(|_| run(&bytes, csv))
            .map(|(n, s)| n as f64 / s)
            .fold(0.0, f64::max);
        println!("{name:24} {:7.2} million samples/s (best of 5)", best / 1e6);
    }
}
