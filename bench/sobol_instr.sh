#!/usr/bin/env bash
# Instructions per Sobol' sample (renderer/core/sobol.h), counted by callgrind: bench/sobol_instr.c
# is built with the renderer's optimisation flags and run at two loop lengths, and the difference
# of the two totals over the difference of the draws is the cost of one draw (start-up cancels;
# the loop's own bookkeeping, a few instructions, is included). Modes: sobol_2d, sobol_1d, two
# rng_next_float for comparison, and the batch functions pt uses: sobol_batch_draw of 8 lanes (a
# sample's dimensions) and sobol_batch_seed of 8 lanes (a pixel's seeds), on this processor's
# widest code path (AVX2, SSE4.1 or scalar). Prints one JSON object. Needs valgrind.
set -euo pipefail
cd "$(dirname "$0")/.."
command -v valgrind >/dev/null || { echo '{"error":"valgrind not installed"}'; exit 0; }
out=build/bench/sobol
mkdir -p "$out"
cc -std=c17 -D_DEFAULT_SOURCE -Wall -Wextra -O3 -fno-math-errno -Irenderer bench/sobol_instr.c -o "$out/sobol_instr"
instr() {  # callgrind's instruction total of one run
    valgrind --tool=callgrind --callgrind-out-file="$out/cg.out" "$out/sobol_instr" "$1" "$2" >/dev/null 2>"$out/vg.txt"
    grep -o 'Collected : [0-9]*' "$out/vg.txt" | awk '{print $3}'
}
lo=100000 hi=1100000
args=()
for mode in 2d 1d random2d batch seed; do args+=("$mode" "$(instr "$mode" $lo)" "$(instr "$mode" $hi)"); done
/usr/bin/python3 - $lo $hi "${args[@]}" <<'PY'
import json, sys
lo, hi = int(sys.argv[1]), int(sys.argv[2])
rest = sys.argv[3:]
res = {}
for i in range(0, len(rest), 3):
    mode, a, b = rest[i], int(rest[i + 1]), int(rest[i + 2])
    res[{"2d": "sobol_2d", "1d": "sobol_1d", "random2d": "rng_next_float_x2", "batch": "sobol_batch_draw_8_lanes",
         "seed": "sobol_batch_seed_8_lanes"}[mode]] = round((b - a) / (hi - lo), 1)
print(json.dumps({"instr_per_draw": res, "command": "bash bench/sobol_instr.sh"}))
PY
