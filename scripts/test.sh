#!/usr/bin/env bash
# Run every test of the project on a fresh Debian machine: installs the thumb target and
# qemu-system-arm when missing, then format check, clippy, host/core tests, firmware builds and the
# QEMU tests (on-chip accuracy, end-to-end streaming). `.ci/run` calls exactly this.
set -euo pipefail
cd "$(dirname "$0")/.."

step() { printf '\n==> %s\n' "$*"; }

as_root() { if [ "$(id -u)" = 0 ]; then "$@"; else sudo "$@"; fi; }

step "toolchain: thumbv7em-none-eabihf target, rustfmt, clippy"
rustup target list --installed | grep -qx thumbv7em-none-eabihf || rustup target add thumbv7em-none-eabihf
rustup component list --installed | grep -q '^rustfmt' || rustup component add rustfmt
rustup component list --installed | grep -q '^clippy' || rustup component add clippy

step "qemu-system-arm"
if ! command -v qemu-system-arm >/dev/null; then
  as_root apt-get update -qq
  DEBIAN_FRONTEND=noninteractive as_root apt-get install -y -qq qemu-system-arm >/dev/null
fi
qemu-system-arm --version | head -1

step "cargo fmt --check"
cargo fmt --all -- --check

step "clippy (host crates, all targets)"
cargo clippy --all-targets -- -D warnings

step "firmware: build (board + qemu) and clippy"
scripts/fw-build.sh
cargo clippy -p jdbb-firmware --release --target thumbv7em-none-eabihf -- -D warnings
cargo clippy -p jdbb-firmware --release --target thumbv7em-none-eabihf --target-dir target/qemu \
  --no-default-features --features qemu --bins -- -D warnings

step "tests (core, host, integration incl. QEMU)"
JDBB_REQUIRE_QEMU=1 cargo test
