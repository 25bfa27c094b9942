#!/usr/bin/env bash
# Issue 8 §6, memory: `jdbb diagnose --record --plan` on a record of about 35 M samples (the size
# of the file that once took 6.4 GB): 12 circles (6 radii × 2 heights) at 1000 mm/min sampled at
# 20 kHz, about 29 minutes of machine time and 1.6 GB of CSV, from the G-code machine simulator of
# the tests (6 µm X backlash, feed override 98 %, clock 37 ppm, 0.2 µm noise). Prints wall time
# and peak memory. Needs about 2 GB free in out/; removes the record at the end.
set -euo pipefail
cd "$(dirname "$0")/.."
cargo build --release -q -p jdbb
cargo build --release -q -p jdbb-tests --example gmachine_record
export PATH="$PWD/target/release:$PATH"
mkdir -p out
radii=()
for r in 98 95 92 89 86 83; do radii+=(--radius "$r"); done
jdbb plan "${radii[@]}" --height 0 --height 8 --feed 1000 --centre 0,0,0 \
  --out out/bench35-plan --force > /dev/null
/usr/bin/time -f "record written: %e s wall, %M KiB peak RSS" \
  target/release/examples/gmachine_record --program out/bench35-plan/ballbar.ngc --centre 0,0,0 \
  --rate 20000 --backlash-x-um 6 --feed-override-pct 98 --clock-ppm 37 --noise-um 0.2 --seed 1 \
  --out out/bench35-rec.csv
ls -l out/bench35-rec.csv
/usr/bin/time -f "diagnose: %e s wall, %U s user, %M KiB peak RSS" \
  jdbb diagnose --record out/bench35-rec.csv --plan out/bench35-plan/plan.json \
  > out/bench35-diagnosis.txt
grep -E "^(synchronised|feed on|[0-9]+ samples|step|not significant|final)" out/bench35-diagnosis.txt
rm -f out/bench35-rec.csv
