#!/usr/bin/env bash
# Build the firmware in release: the real board (STM32F411 "Black Pill", USB CDC) and the QEMU
# build (netduinoplus2: simulated encoders, USART2) with its test programs `accuracy` and `cycles`.
# The QEMU build has its own target dir so the two `jdbb-firmware` ELFs don't overwrite each other.
# Assumes the thumbv7em-none-eabihf target is installed (scripts/test.sh installs it).
set -euo pipefail
cd "$(dirname "$0")/.."

TARGET=thumbv7em-none-eabihf
cargo build -p jdbb-firmware --release --target "$TARGET" --bin jdbb-firmware
cargo build -p jdbb-firmware --release --target "$TARGET" --target-dir target/qemu \
  --no-default-features --features qemu --bins

echo "board firmware: target/$TARGET/release/jdbb-firmware"
echo "qemu firmware:  target/qemu/$TARGET/release/jdbb-firmware"
echo "qemu programs:  target/qemu/$TARGET/release/accuracy, target/qemu/$TARGET/release/cycles"
