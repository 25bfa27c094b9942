#!/usr/bin/env sh
# Issue 3 speed, Rust vs Python, on the same 20,000 samples from one run each: `jdbb simulate`
# writes one circle ccw + cw at R = 50 mm (set-up offset, scale_x, backlash_y, cyclic_x, 0.3 um
# noise), then `host/benches/diagnose.rs` and `bench/diagnose.py` (numpy/scipy) each time the
# whole diagnosis (candidate search included) of that file; prints both and the ratio.
# usage: bench/compare_diagnose.sh   (from anywhere; builds the release binary and the bench)
set -eu
cd "$(dirname "$0")/.."
export OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 MKL_NUM_THREADS=1
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
cargo build -q --release -p jdbb --bin jdbb
cargo bench -q -p jdbb --bench diagnose --no-run
# 10,000 samples per circle: rate = 10000 / (2*pi*50 mm / (1000/60 mm/s)).
./target/release/jdbb simulate --radius 50 --feed 1000 --rate 530.516477 --pitch x=10,y=10 \
  --effect setup_offset=30,-20,0 --effect scale_x=20 --effect backlash_y=8 --effect cyclic_x=2@40 \
  --sigma-um 0.3 --resolution-um 0.1 --seed 1 -o "$tmp/samples.csv"
rust_out=$(taskset -c 0 cargo bench -q -p jdbb --bench diagnose -- "$tmp/samples.csv")
echo "$rust_out"
py_out=$(taskset -c 0 python3 bench/diagnose.py "$tmp/samples.csv" x=10,y=10)
echo "$py_out"
rust=$(echo "$rust_out" | sed -n 's/^diagnose .* median \([0-9.]*\) ms.*/\1/p')
rust_min=$(echo "$rust_out" | sed -n 's/^diagnose .* min \([0-9.]*\) ms.*/\1/p')
py=$(echo "$py_out" | sed -n 's/^python diagnose .* median \([0-9.]*\) ms.*/\1/p')
py_min=$(echo "$py_out" | sed -n 's/^python diagnose .* min \([0-9.]*\) ms.*/\1/p')
echo "ratio python/rust: median $(echo "$py / $rust" | bc -l | cut -c1-5)x (rust ${rust} ms, python ${py} ms), min $(echo "$py_min / $rust_min" | bc -l | cut -c1-5)x (rust ${rust_min} ms, python ${py_min} ms); one core each"
