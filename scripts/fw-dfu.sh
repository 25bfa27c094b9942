#!/usr/bin/env bash
# First flash of the board over USB, with no probe: the STM32F411's ROM DFU bootloader.
#
#   scripts/fw-dfu.sh [--features hse-8mhz|hse-12mhz|hse-16mhz|hse-24mhz]
#
# 1. Builds the board firmware in release (crystal 25 MHz unless a feature says otherwise).
# 2. Turns the ELF into a raw binary image for address 0x08000000 (`jdbb.bin`): with
#    arm-none-eabi-objcopy (Debian: `apt-get install binutils-arm-none-eabi`) if installed, else
#    rust-objcopy (`cargo install cargo-binutils` and `rustup component add llvm-tools`).
# 3. Waits for the board in DFU mode (0483:df11) and writes the image with dfu-util (Debian:
#    `apt-get install dfu-util`), `:leave` starting the firmware afterwards.
#
# DFU mode on the WeAct Black Pill: hold BOOT0, press and release NRST, release BOOT0 (with USB
# plugged in). `dfu-util -l` then lists "@Internal Flash /0x08000000/...". If it does not appear,
# repeat with the board warm or press NRST again while holding BOOT0 (a known quirk of the F411's
# bootloader with some USB hosts).
# Waits DFU_WAIT_S seconds (default 60) for the board. Exits nonzero, saying why, if a tool is
# missing, no board appears or dfu-util fails.
set -euo pipefail
cd "$(dirname "$0")/.."

TARGET=thumbv7em-none-eabihf
FEATURES=()
while [ $# -gt 0 ]; do
  case "$1" in
    --features) FEATURES=(--features "$2"); shift 2 ;;
    -h|--help) sed -n '2,18p' "$0"; exit 0 ;;
    *) echo "fw-dfu.sh: unknown argument '$1' (try --help)" >&2; exit 2 ;;
  esac
done

cargo build -p jdbb-firmware --release --target "$TARGET" --bin jdbb-firmware "${FEATURES[@]}"
ELF="target/$TARGET/release/jdbb-firmware"
BIN="target/$TARGET/release/jdbb.bin"
if command -v arm-none-eabi-objcopy >/dev/null; then
  arm-none-eabi-objcopy -O binary "$ELF" "$BIN"
elif command -v rust-objcopy >/dev/null; then
  rust-objcopy -O binary "$ELF" "$BIN"
else
  echo "fw-dfu.sh: no objcopy: apt-get install binutils-arm-none-eabi, or cargo install cargo-binutils && rustup component add llvm-tools" >&2
  exit 1
fi
echo "image: $BIN ($(wc -c <"$BIN") bytes, for 0x08000000)"

if ! command -v dfu-util >/dev/null; then
  echo "fw-dfu.sh: dfu-util not found: apt-get install dfu-util" >&2
  exit 1
fi
echo "waiting for the board in DFU mode (hold BOOT0, tap NRST, release BOOT0)..."
for _ in $(seq "${DFU_WAIT_S:-60}"); do
  dfu-util -l 2>/dev/null | grep -q '0483:df11' && break
  sleep 1
done
dfu-util -l 2>/dev/null | grep -q '0483:df11' || {
  echo "fw-dfu.sh: no DFU device (0483:df11) after ${DFU_WAIT_S:-60} s" >&2
  exit 1
}
dfu-util -d 0483:df11 -a 0 -s 0x08000000:leave -D "$BIN"
echo "flashed; the firmware starts (a board that stays in the bootloader: press NRST)"
