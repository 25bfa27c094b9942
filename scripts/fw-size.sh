#!/usr/bin/env bash
# Flash and RAM used by the release firmware builds (run scripts/fw-build.sh first).
#   flash = every allocated section that has contents (vector table, .text, .rodata, .data's
#           initial values);
#   RAM   = every allocated writable section (.data + .bss + .uninit): static RAM, excluding the
#           stack, which cortex-m-rt gives the rest of RAM.
# Reads the ELF32 section headers with od (coreutils): no binutils or llvm-tools needed. Exits 1
# when a build is over the budget it prints (scripts/test.sh enforces it in CI).
set -euo pipefail
cd "$(dirname "$0")/.."

TARGET=thumbv7em-none-eabihf
u() { od -An -v -t "u$2" -j "$3" -N "$2" "$1" | tr -d ' '; } # file, bytes, offset

elf_size() {
  local elf=$1 label=$2
  [ -f "$elf" ] || { echo "$elf: not built (run scripts/fw-build.sh)" >&2; return 1; }
  [ "$(od -An -c -N 4 "$elf" | tr -d ' ')" = '177ELF' ] || { echo "$elf: not an ELF file" >&2; return 1; }
  local shoff shentsize shnum shstrndx stroff
  shoff=$(u "$elf" 4 32); shentsize=$(u "$elf" 2 46); shnum=$(u "$elf" 2 48); shstrndx=$(u "$elf" 2 50)
  stroff=$(u "$elf" 4 $((shoff + shstrndx * shentsize + 16)))
  local flash=0 ram=0 i base name type flags size sections=""
  for ((i = 1; i < shnum; i++)); do
    base=$((shoff + i * shentsize))
    type=$(u "$elf" 4 $((base + 4))); flags=$(u "$elf" 4 $((base + 8))); size=$(u "$elf" 4 $((base + 20)))
    (( flags & 2 )) || continue # SHF_ALLOC
    (( size > 0 )) || continue
    name=$(dd if="$elf" bs=1 skip=$((stroff + $(u "$elf" 4 "$base"))) count=64 2>/dev/null | tr '\0' '\n' | head -n1)
    sections="$sections $name=$size"
    (( type != 8 )) && flash=$((flash + size))    # not SHT_NOBITS: stored in flash
    (( flags & 1 )) && ram=$((ram + size))        # SHF_WRITE: lives in RAM
  done
  kib() { awk -v b="$1" 'BEGIN { printf "%.1f", b / 1024 }'; }
  printf '%-30s flash %7d B (%s KiB)   RAM %6d B (%s KiB)\n' "$label" "$flash" "$(kib "$flash")" \
    "$ram" "$(kib "$ram")"
  printf '    sections:%s\n' "$sections"
  if (( flash > FLASH_BUDGET || ram > RAM_BUDGET )); then
    echo "$label: over budget (flash $flash B of $FLASH_BUDGET, RAM $ram B of $RAM_BUDGET)" >&2
    over=1
  fi
}
# 128 KiB: flash sectors 0-4 (4 x 16 KiB + 64 KiB); sector 5 stays free, 6-7 hold the calibration
# store (memory.x gives the program the first 256 KiB).
FLASH_BUDGET=$((128 * 1024))
RAM_BUDGET=$((32 * 1024))
over=0

elf_size "target/$TARGET/release/jdbb-firmware" "board (STM32F411, USB CDC)"
elf_size "target/qemu/$TARGET/release/jdbb-firmware" "qemu (netduinoplus2, USART2)"
echo "budget: flash <= 128 KiB (sectors 0-4), RAM <= 32 KiB (STM32F411CE has 512 KiB flash, 128 KiB RAM)"
exit "$over"
