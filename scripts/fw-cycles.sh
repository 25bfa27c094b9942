#!/usr/bin/env bash
# Per-sample cost of the on-chip sample path (counts -> D -> batch -> frame bytes) in instructions,
# measured on the Cortex-M4F under QEMU with -icount shift=0 (deterministic: 1 instruction = 1 ns
# of virtual time; SysTick is calibrated against a loop of known length). Builds the program if
# needed. Prints the `cycles` program's report; exits nonzero if it fails or if the worst sample
# path is over the budget the report states (scripts/test.sh enforces it in CI).
set -euo pipefail
cd "$(dirname "$0")/.."

TARGET=thumbv7em-none-eabihf
cargo build -q -p jdbb-firmware --release --target "$TARGET" --target-dir target/qemu \
  --no-default-features --features qemu --bin cycles
report=$(timeout 120 qemu-system-arm -machine netduinoplus2 -nographic -monitor none -icount shift=0 \
  -serial null -serial null -semihosting-config enable=on,target=native \
  -kernel "target/qemu/$TARGET/release/cycles")
echo "$report"
worst=$(echo "$report" | sed -n 's/^worst sample path: \([0-9]*\) instructions\/sample (budget \([0-9]*\)).*/\1 \2/p')
[ -n "$worst" ] || { echo "fw-cycles.sh: the report has no 'worst sample path' line" >&2; exit 1; }
set -- $worst
if [ "$1" -gt "$2" ]; then
  echo "fw-cycles.sh: the sample path takes $1 instructions per sample, over its budget of $2" >&2
  exit 1
fi
