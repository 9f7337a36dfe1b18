#!/usr/bin/env bash
# The path tracer's instructions per ray, counted by callgrind, against the budget kept in
# tests/perf/instr_budget.json (`make test-perf`, part of `make test`). Instruction counts of one
# binary are the same in every run, whatever else the machine is doing, so unlike a timing this
# can fail a build: a change that makes the path loop do more work per ray fails here.
# Start-up (scene load, BVH build, EXR writing) cancels out: the render runs at two sample
# counts and only the differences are used, as in bench/instr_per_ray.sh.
# Environment: RESTIR_BIN (default build/restir), INSTR_BUDGET (default the file above).
# Exit status: 0 within budget (or skipped: no valgrind), 1 over budget, 2 could not measure.
set -euo pipefail
cd "$(dirname "$0")/../.."
bin=${RESTIR_BIN:-build/restir}
budget=${INSTR_BUDGET:-tests/perf/instr_budget.json}
if ! command -v valgrind >/dev/null; then
    echo "test-perf: skipped: valgrind is not installed (Debian package valgrind, scripts/install-deps.sh)"
    exit 0
fi
[ -x "$bin" ] || { echo "test-perf: $bin: no such program (run make first)" >&2; exit 2; }
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT

# The measured render (the CLI's random streams are fixed by default, so are its rays); the
# budget file records the same words (checked below), so a figure is
# never compared with a budget set for another command.
scene=scenes/cornell-box/scene.json
args=(--method pt --size 64x64 --threads 1 --max-depth 8)
spp_lo=4 spp_hi=12
command_text="restir render $scene ${args[*]} --spp {$spp_lo,$spp_hi}"

rays() {
    "$bin" render "$scene" "${args[@]}" --spp "$1" --json -o "$work/r.exr" |
        /usr/bin/python3 -c "import json,sys;print(json.load(sys.stdin)['rays'])"
}
instr() {
    valgrind --tool=callgrind --callgrind-out-file="$work/cg.out" "$bin" render "$scene" "${args[@]}" --spp "$1" \
        -o "$work/i.exr" >/dev/null 2>"$work/vg.txt"
    grep -o 'Collected : [0-9]*' "$work/vg.txt" | awk '{print $3}'
}
r_lo=$(rays $spp_lo) r_hi=$(rays $spp_hi)
i_lo=$(instr $spp_lo) i_hi=$(instr $spp_hi)
[ -n "$i_lo" ] && [ -n "$i_hi" ] || { echo "test-perf: callgrind reported no count:" >&2; cat "$work/vg.txt" >&2; exit 2; }

/usr/bin/python3 - "$budget" "$command_text" "$r_lo" "$r_hi" "$i_lo" "$i_hi" <<'PY'
import json, sys
path, command = sys.argv[1], sys.argv[2]
r_lo, r_hi, i_lo, i_hi = map(int, sys.argv[3:])
b = json.load(open(path))
if b["command"] != command:
    print(f"test-perf: {path}: /command is {b['command']!r}, this test runs {command!r}", file=sys.stderr)
    sys.exit(2)
per_ray = (i_hi - i_lo) / (r_hi - r_lo)
limit = b["instr_per_ray"] * (1.0 + b["tolerance"])
verdict = "ok" if per_ray <= limit else "OVER BUDGET"
print(f"test-perf: pt, {per_ray:.1f} instructions per ray ({i_hi - i_lo} instructions / {r_hi - r_lo} rays); "
      f"budget {b['instr_per_ray']} + {b['tolerance'] * 100:g} % = {limit:.1f}: {verdict}")
if per_ray > limit:
    print(f"test-perf: the path loop does more work per ray than {path} allows; find where with "
          f"valgrind --tool=callgrind and callgrind_annotate (docs/benchmarks.md)", file=sys.stderr)
    sys.exit(1)
PY
