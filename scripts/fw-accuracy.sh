#!/usr/bin/env bash
# On-chip accuracy run: evaluates D on the Cortex-M4F (QEMU netduinoplus2) over a grid of counts
# covering the frames' working range and writes the result frames (USART2 bytes: DeviceMsg::Info
# then DeviceMsg::Batch frames per calibration, see firmware/src/bin/accuracy.rs) to OUT
# (default target/qemu/accuracy.bin). The host-side comparison with the f64 reference is the
# `qemu` integration test. Exits nonzero if the program fails.
set -euo pipefail
cd "$(dirname "$0")/.."

TARGET=thumbv7em-none-eabihf
OUT=${1:-target/qemu/accuracy.bin}
cargo build -q -p jdbb-firmware --release --target "$TARGET" --target-dir target/qemu \
  --no-default-features --features qemu --bin accuracy
mkdir -p "$(dirname "$OUT")"
timeout 120 qemu-system-arm -machine netduinoplus2 -nographic -monitor none \
  -serial null -serial "file:$OUT" -semihosting-config enable=on,target=native \
  -kernel "target/qemu/$TARGET/release/accuracy"
echo "accuracy frames: $OUT ($(wc -c <"$OUT") bytes)"
