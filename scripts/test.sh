#!/usr/bin/env bash
# Run every test of the project on a fresh Debian machine: installs the thumb target and
# qemu-system-arm when missing, then format check, clippy, host/core tests, firmware builds and the
# QEMU tests (on-chip accuracy, end-to-end streaming). `.ci/run` calls exactly this.
set -euo pipefail
cd "$(dirname "$0")/.."

step() { printf '\n==> %s\n' "$*"; }

step "toolchain and QEMU: thumbv7em-none-eabihf, rustfmt, clippy, qemu-system-arm"
scripts/setup.sh
qemu-system-arm --version | head -1

step "cargo fmt --check"
cargo fmt --all -- --check

step "clippy (host crates, all targets; about 3 min on 2 cores the first time)"
cargo clippy --all-targets -- -D warnings

step "firmware: build (board + qemu), flash/RAM and instructions-per-sample budgets, clippy (about 2 min the first time)"
scripts/fw-build.sh
scripts/fw-size.sh        # fails above the flash/RAM budget
scripts/fw-cycles.sh      # fails above the instructions-per-sample budget
cargo clippy -p jdbb-firmware --release --target thumbv7em-none-eabihf -- -D warnings
cargo clippy -p jdbb-firmware --release --target thumbv7em-none-eabihf --target-dir target/qemu \
  --no-default-features --features qemu --bins -- -D warnings

step "tests (core, host, README examples, integration incl. QEMU; about 4 min to build the first time)"
JDBB_REQUIRE_QEMU=1 JDBB_REQUIRE_CHROMIUM=1 JDBB_REQUIRE_POSTGRES=1 cargo test
