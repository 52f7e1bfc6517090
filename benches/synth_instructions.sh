#!/usr/bin/env bash
# Instructions per synthesised sample, counted by callgrind (not timed, so the figure does
# not depend on the machine's load): the difference of 60 and 20 blocks of 4096 samples of
# `examples/synth_blocks.rs`, so the start-up is left out. valgrind has no AVX-512: the
# AVX2 build is the one counted. Needs valgrind.
#
#   bash benches/synth_instructions.sh                 # the four cases of docs/benchmarks.md
#   bash benches/synth_instructions.sh coupled 20e-9 on
#   bash benches/synth_instructions.sh coupled 20e-9 on window   # the synthesiser thread's part
#   bash benches/synth_instructions.sh coupled 20e-9 on window substeps=6   # at 6 sub-steps
set -euo pipefail
cd "$(dirname "$0")/.."
cargo build --release --example synth_blocks >&2
bin=target/release/examples/synth_blocks
count() {
  valgrind --tool=callgrind --callgrind-out-file=/dev/null "$bin" "$@" 2>&1 |
    awk '/refs:/ { gsub(",", "", $4); print $4 }'
}
measure() {
  local a b
  a=$(count "$@" 20)
  b=$(count "$@" 60)
  python3 -c "print('$*:', round(($b - $a) / (40 * 4096), 1), 'instructions a sample')"
}
if [ $# -gt 0 ]; then
  measure "$@"
else
  measure paper 20e-9 on
  measure coupled 20e-9 on
  measure coupled 50e-9 on
  measure coupled 50e-9 off
fi
