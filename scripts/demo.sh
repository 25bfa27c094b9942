#!/usr/bin/env bash
# The main job on the embedded default, on a fresh Debian machine:
#   builds the QEMU firmware and the host, starts the firmware in QEMU (netduinoplus2: a simulated
#   circular test, R = 90 mm at 1000 mm/min, through the same sample path as the real board),
#   shows it in `jdbb live` for a few seconds, then records a few seconds to out/demo.csv.
#
#   scripts/demo.sh [SECONDS]      (default 5 s for each of live and record)
set -euo pipefail
cd "$(dirname "$0")/.."
SECS=${1:-5}

scripts/setup.sh
echo "==> building the QEMU firmware (release; about 1 min on 2 cores the first time)"
cargo build -p jdbb-firmware --release --target thumbv7em-none-eabihf --target-dir target/qemu \
  --no-default-features --features qemu --bin jdbb-firmware
echo "==> building the host, jdbb (release; about 3 min on 2 cores the first time)"
cargo build -p jdbb --release
JDBB=target/release/jdbb

echo "==> starting the firmware in QEMU"
mkdir -p out
coproc QEMU { exec scripts/qemu-run.sh; }
QEMU_RUN_PID=$QEMU_PID
trap 'kill "$QEMU_RUN_PID" 2>/dev/null || true; wait "$QEMU_RUN_PID" 2>/dev/null || true' EXIT
read -r PTY <&"${QEMU[0]}"
echo "    USART2 of the emulated board is $PTY"

echo "==> jdbb live --port $PTY --seconds $SECS"
"$JDBB" live --port "$PTY" --seconds "$SECS"

echo "==> jdbb record --port $PTY --out out/demo.csv --seconds $SECS --force"
"$JDBB" record --port "$PTY" --out out/demo.csv --seconds "$SECS" --force  # the demo replaces its own file

echo "==> out/demo.csv: $(($(grep -vc '^#' out/demo.csv) - 1)) samples; first lines:"
head -n 4 out/demo.csv
