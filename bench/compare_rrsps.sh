#!/usr/bin/env sh
# Seed 004 identification speed, Rust vs Python, on the same 100,000 samples from one run each:
# simulates the Table 2 motion (M1 truth, 0.45 um noise), then times `host/benches/rrsps.rs`
# and `bench/rrsps.py` (scipy.optimize.least_squares) on that file and prints the ratio.
# usage: bench/compare_rrsps.sh   (from the repo root; needs the shared data table or uses Table 2 below)
set -eu
cd "$(dirname "$0")/.."
export OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 MKL_NUM_THREADS=1
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
cat > "$tmp/design.toml" <<T
s0_mm = 96.310
a0_mm = 352.114
theta_a0_deg = -55.0
s2_mm = 80.0
a2_mm = 30.0
theta_c0_deg = -161.592
a1_mm = 0.0
alpha12_deg = 270.0
T
cat > "$tmp/m1.toml" <<T
s0_mm = 96.865
a0_mm = 351.891
theta_a0_deg = -54.995
s2_mm = 79.871
a2_mm = 30.063
theta_c0_deg = -161.531
a1_mm = -0.023
alpha12_deg = 270.093
T
cargo build -q --release -p jdbb --bin jdbb
./target/release/jdbb rrsps simulate --design "$tmp/design.toml" --truth "$tmp/m1.toml" --d 300 \
  --points 50000 --noise-um 0.45 --seed 1 -o "$tmp/samples.csv" 2>/dev/null
rust_out=$(cargo bench -q -p jdbb --bench rrsps -- "$tmp/samples.csv")
echo "$rust_out"
rust=$(echo "$rust_out" | sed -n 's/^rrsps lsq: .*median \([0-9.]*\) ms.*/\1/p')
py=$(python3 bench/rrsps.py "$tmp/samples.csv")
echo "$py"
lm=$(echo "$py" | sed -n 's/^scipy least_squares lm: .*median \([0-9.]*\) ms.*/\1/p')
trf=$(echo "$py" | sed -n 's/^scipy least_squares trf: .*median \([0-9.]*\) ms.*/\1/p')
echo "ratio python/rust: lm $(echo "$lm / $rust" | bc -l | cut -c1-5)x, trf $(echo "$trf / $rust" | bc -l | cut -c1-5)x (rust ${rust} ms, lm ${lm} ms, trf ${trf} ms)"
