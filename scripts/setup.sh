#!/usr/bin/env bash
# Install what the firmware build and the QEMU runs need, when missing: the thumbv7em-none-eabihf
# target, rustfmt/clippy, and Debian's qemu-system-arm; and headless Chromium for the report
# rendering test and poppler-utils for the PDF report test (required: setup fails loudly when it
# cannot be installed, and test.sh sets JDBB_REQUIRE_CHROMIUM=1 so that test cannot skip); and
# Debian's PostgreSQL server for the history tests on a server (JDBB_REQUIRE_POSTGRES=1
# likewise). Safe to run again. Sourced by test.sh and
# demo.sh.
set -euo pipefail

as_root() { if [ "$(id -u)" = 0 ]; then "$@"; else sudo "$@"; fi; }

rustup target list --installed | grep -qx thumbv7em-none-eabihf || rustup target add thumbv7em-none-eabihf
rustup component list --installed | grep -q '^rustfmt' || rustup component add rustfmt
rustup component list --installed | grep -q '^clippy' || rustup component add clippy
if ! command -v qemu-system-arm >/dev/null; then
  as_root apt-get update -qq
  DEBIAN_FRONTEND=noninteractive as_root apt-get install -y -qq qemu-system-arm >/dev/null
fi
if ! command -v chromium >/dev/null && ! command -v chromium-headless-shell >/dev/null; then
  if ! { as_root apt-get update -qq && DEBIAN_FRONTEND=noninteractive as_root apt-get install -y -qq chromium >/dev/null; }; then
    echo "setup.sh: could not install chromium (Debian's package): the report rendering test needs it" >&2
    exit 1
  fi
fi
# Debian's PostgreSQL server for the history tests on a server (host/tests/common/pg.rs starts a
# throwaway cluster from /usr/lib/postgresql/*/bin; test.sh sets JDBB_REQUIRE_POSTGRES=1).
if ! ls /usr/lib/postgresql/*/bin/initdb >/dev/null 2>&1; then
  if ! { as_root apt-get update -qq && DEBIAN_FRONTEND=noninteractive as_root apt-get install -y -qq postgresql >/dev/null; }; then
    echo "setup.sh: could not install postgresql (Debian's package): the history tests on a server need it" >&2
    exit 1
  fi
fi
if ! command -v pdftotext >/dev/null || ! command -v pdftoppm >/dev/null; then
  if ! { as_root apt-get update -qq && DEBIAN_FRONTEND=noninteractive as_root apt-get install -y -qq poppler-utils >/dev/null; }; then
    echo "setup.sh: could not install poppler-utils (Debian's package): the PDF report test reads page one with pdftotext and pdftoppm" >&2
    exit 1
  fi
fi
