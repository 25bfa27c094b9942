#!/usr/bin/env bash
# Issue 8 §6 / issue 15 §6: plan + synchronisation + diagnosis of a 10-minute record of four radii
# at 1704 Hz (about 1 M samples), on one core (taskset -c 0), with its peak memory. The record comes from the G-code machine simulator of
# the tests (6 µm X backlash, feed override 98 %, clock 37 ppm, 0.2 µm noise).
set -euo pipefail
cd "$(dirname "$0")/.."
cargo build --release -q -p jdbb
cargo build --release -q -p jdbb-tests --example gmachine_record
export PATH="$PWD/target/release:$PATH"
mkdir -p out
jdbb plan --radius 98 --radius 94 --radius 90 --radius 86 --feed 1000 --centre 0,0,0 \
  --out out/bench-plan --force > /dev/null
target/release/examples/gmachine_record --program out/bench-plan/ballbar.ngc --centre 0,0,0 \
  --rate 1704 --backlash-x-um 6 --feed-override-pct 98 --clock-ppm 37 --noise-um 0.2 --seed 1 \
  --out out/bench-rec.csv
for run in 1 2 3; do
  /usr/bin/time -f "run $run: %e s wall, %U s user, %M KiB peak RSS" \
    taskset -c 0 jdbb diagnose --record out/bench-rec.csv --plan out/bench-plan/plan.json \
    > out/bench-diagnosis.txt
done
grep -E "^(synchronised|feed on|step|not significant|final)" out/bench-diagnosis.txt
