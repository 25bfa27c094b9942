#!/usr/bin/env bash
# Run the QEMU build of the firmware (netduinoplus2: simulated circular test, USART2) with USART2
# on a pseudo-terminal, for `jdbb live --port PTY` / `jdbb record --port PTY`.
#
#   scripts/qemu-run.sh [--seconds N] [--elf PATH] [--icount] [--scenario FILE]
#
# `--scenario FILE` plays a scenario file (format: `jdbb_core::scenario`; made by the tests'
# G-code machine simulator, e.g. `cargo run -p jdbb-tests --example gmachine_record -- ...
# --scenario FILE`) as the encoders instead of the built-in circle: each run (each Start) plays
# it from its first record. Record it at the scenario's own rate under `--icount`.
#
# By default QEMU runs on the host's clock: the stream is real time (1 kHz at boot). If the host
# starves QEMU, or a high rate makes the simulated encoders' ~33 000 instructions per sample add
# up (above ~2 kHz), the emulated CPU overruns and the firmware drops samples, counted in
# `dropped`, as an overloaded real device would. `--icount` adds `-icount shift=0,sleep=off`: one
# instruction per ns of emulated time, and idle time skipped, so the stream runs faster than real
# time at low rates, slower at high ones, and never overruns: lossless and reproducible, for tests.
#
# Prints the pty path alone on the first line of stdout as soon as QEMU has created it, e.g.
#   /dev/pts/5
# then keeps QEMU running until it is interrupted (Ctrl-C, SIGTERM), for N seconds if given, or
# until QEMU exits; QEMU is killed when this script exits, whatever the reason. The firmware starts
# sampling at 1 kHz at boot. Bytes written while no program has the pty open are discarded by QEMU
# (so the boot-time DeviceInfo is usually missed: send GetInfo or Start). QEMU's own messages and
# then the firmware's defmt log (binary, via semihosting on QEMU's stdout) go to
# target/qemu/qemu.log.
# Builds the firmware first if it is missing.
set -euo pipefail
cd "$(dirname "$0")/.."

TARGET=thumbv7em-none-eabihf
ELF="target/qemu/$TARGET/release/jdbb-firmware"
SECONDS_TO_RUN=""
ICOUNT=""
SCENARIO=""
while [ $# -gt 0 ]; do
  case "$1" in
    --seconds) SECONDS_TO_RUN=$2; shift 2 ;;
    --elf) ELF=$2; shift 2 ;;
    --icount) ICOUNT="-icount shift=0,sleep=off"; shift ;;
    --scenario) SCENARIO=$2; shift 2 ;;
    -h|--help) sed -n '2,28p' "$0"; exit 0 ;;
    *) echo "qemu-run.sh: unknown argument '$1' (try --help)" >&2; exit 2 ;;
  esac
done

if [ ! -f "$ELF" ]; then
  cargo build -q -p jdbb-firmware --release --target "$TARGET" --target-dir target/qemu \
    --no-default-features --features qemu --bin jdbb-firmware >&2
fi

SEMIHOSTING="enable=on,target=native"
if [ -n "$SCENARIO" ]; then
  if [ ! -f "$SCENARIO" ] || [ ! -r "$SCENARIO" ]; then
    echo "qemu-run.sh: --scenario $SCENARIO: no such readable file" >&2
    exit 2
  fi
  if [ "$(head -c 8 "$SCENARIO")" != "JDBBSCEN" ]; then
    echo "qemu-run.sh: --scenario $SCENARIO: not a scenario file (it does not begin with JDBBSCEN)" >&2
    exit 2
  fi
  # The firmware reads the path from the semihosting command line (second word); QEMU's option
  # syntax needs commas doubled.
  ABS=$(realpath "$SCENARIO")
  SEMIHOSTING="$SEMIHOSTING,arg=jdbb-firmware,arg=${ABS//,/,,}"
fi

mkdir -p target/qemu
LOG=target/qemu/qemu.log
: >"$LOG"
qemu-system-arm -machine netduinoplus2 -nographic -monitor none $ICOUNT \
  -serial null -serial pty \
  -semihosting-config "$SEMIHOSTING" \
  -kernel "$ELF" >"$LOG" 2>&1 &
QEMU_PID=$!
cleanup() {
  # QEMU blocked writing to a full pty (a reader that stopped reading) cannot act on SIGTERM:
  # escalate to SIGKILL after 2 s.
  if kill -0 "$QEMU_PID" 2>/dev/null; then
    kill -TERM "$QEMU_PID" 2>/dev/null || true
    for _ in $(seq 20); do
      kill -0 "$QEMU_PID" 2>/dev/null || break
      sleep 0.1
    done
    kill -KILL "$QEMU_PID" 2>/dev/null || true
  fi
  wait "$QEMU_PID" 2>/dev/null || true
}
trap cleanup EXIT
trap 'exit 130' INT
trap 'exit 143' TERM

PTY=""
for _ in $(seq 100); do
  PTY=$(grep -ao 'char device redirected to /dev/[^ ]* (label serial1)' "$LOG" | head -n1 | cut -d' ' -f5 || true)
  [ -n "$PTY" ] && break
  kill -0 "$QEMU_PID" 2>/dev/null || break
  sleep 0.1
done
if [ -z "$PTY" ]; then
  echo "qemu-run.sh: QEMU did not report its pty; its log:" >&2
  grep -a -v '^$' "$LOG" | head -n 20 >&2 || true
  exit 1
fi
echo "$PTY"
echo "qemu-run.sh: QEMU pid $QEMU_PID, USART2 on $PTY (Ctrl-C to stop)" >&2

if [ -n "$SECONDS_TO_RUN" ]; then
  # Sleep in the background so signals interrupt the wait at once.
  sleep "$SECONDS_TO_RUN" &
  wait $! || true
else
  RC=0
  wait "$QEMU_PID" || RC=$?
  if [ "$RC" -ne 0 ]; then
    # The firmware's own words (semihosting) among the binary defmt log, e.g. a refused scenario.
    grep -a -o 'jdbb-firmware: [[:print:]]*' "$LOG" >&2 || true
    echo "qemu-run.sh: QEMU exited with status $RC (log: $LOG)" >&2
    exit 1
  fi
fi
