#!/usr/bin/env bash
# The path tracer's instructions per ray, counted by callgrind, against the budgets kept in
# tests/perf/instr_budget.json (`make test-perf`, part of `make test`). Instruction counts of one
# binary are the same in every run, whatever else the machine is doing, so unlike a timing this
# can fail a build: a change that makes the path loop do more work per ray fails here.
# Three fixed renders are measured: the diffuse Cornell box (the diffuse fast path), the glossy
# Cornell box (conductors and a dielectric: material_sample/eval and the specular chains) and the
# diffuse Cornell box with the Sobol' sampler (the other copy of the tile loop, and sobol.h), each
# against its own budget entry.
# Start-up (scene load, BVH build, EXR writing) cancels out: each render runs at two sample
# counts and only the differences are used, as in bench/instr_per_ray.sh.
# Environment: RESTIR_BIN (default build/restir), INSTR_BUDGET (default the file above),
# VALGRIND (default valgrind).
# Exit status: 0 within budget (or SKIPPED: no valgrind), 1 over budget, 2 could not measure
# (the reason is printed: a failing binary, no callgrind count, no rays to divide by).
set -euo pipefail
cd "$(dirname "$0")/../.."
bin=${RESTIR_BIN:-build/restir}
budget=${INSTR_BUDGET:-tests/perf/instr_budget.json}
valgrind=${VALGRIND:-valgrind}
if ! command -v "$valgrind" >/dev/null; then
    echo "test-perf: SKIPPED: valgrind missing ($valgrind not found; Debian package valgrind," \
         "scripts/install-deps.sh): instructions per ray NOT checked"
    exit 0
fi
[ -x "$bin" ] || { echo "test-perf: $bin: no such program (run make first)" >&2; exit 2; }
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT

# Every failure to measure ends here, so that it can never pass for a verdict on the budget.
cannot_measure() {
    echo "test-perf: could not measure: $1" >&2
    [ $# -lt 2 ] || [ ! -s "$2" ] || { echo "--- $2:" >&2; tail -n 30 "$2" >&2; }
    exit 2
}

# The measured renders: name, scene, arguments (the CLI's random streams are fixed by default,
# so are its rays). The budget file records the same words for each name (checked below), so a
# figure is never compared with a budget set for another command.
spp_lo=4 spp_hi=12
renders=(
    "diffuse|scenes/cornell-box/scene.json|--method pt --size 64x64 --threads 1 --max-depth 8 --frames 1 --params {\"sampler\":\"random\"}"
    "glossy|scenes/cornell-glossy/scene.json|--method pt --size 32x32 --threads 1 --max-depth 8 --frames 1 --params {\"sampler\":\"random\"}"
    "diffuse_sobol|scenes/cornell-box/scene.json|--method pt --size 64x64 --threads 1 --max-depth 8 --frames 1 --params {\"sampler\":\"sobol\"}"
)

# rays SCENE SPP VAR ARGS...: the render's ray count (its --json statistics) into VAR.
rays() {
    local scene=$1 spp=$2 var=$3 n
    shift 3
    "$bin" render "$scene" "$@" --spp "$spp" --json -o "$work/r.exr" >"$work/r.json" 2>"$work/r.txt" ||
        cannot_measure "$bin render $scene --spp $spp failed (status $?)" "$work/r.txt"
    n=$(/usr/bin/python3 -c "import json,sys;print(int(json.load(open(sys.argv[1]))['rays']))" \
        "$work/r.json" 2>>"$work/r.txt") ||
        cannot_measure "$bin render $scene --spp $spp --json printed no /rays" "$work/r.txt"
    printf -v "$var" '%s' "$n"
}
# instr SCENE SPP VAR EVAR ARGS...: the instructions callgrind collected over the whole render into
# VAR, and those of them spent in Embree's library (its functions' own costs, callgrind_annotate)
# into EVAR. The budget holds the whole; the split is printed beside it, so that a change shows
# whether it moved our work or Embree's (docs/benchmarks.md, "Quads merged into one geometry").
instr() {
    local scene=$1 spp=$2 var=$3 evar=$4 n e
    shift 4
    "$valgrind" --tool=callgrind --callgrind-out-file="$work/cg.out" "$bin" render "$scene" "$@" \
        --spp "$spp" -o "$work/i.exr" >/dev/null 2>"$work/vg.txt" ||
        cannot_measure "$valgrind --tool=callgrind $bin render $scene --spp $spp failed (status $?)" "$work/vg.txt"
    n=$(grep -o 'Collected : [0-9]*' "$work/vg.txt" | awk '{print $3}') || true
    [ -n "$n" ] || cannot_measure "callgrind printed no 'Collected :' line for $scene --spp $spp" "$work/vg.txt"
    e=$(callgrind_annotate --inclusive=no --threshold=100 --auto=no "$work/cg.out" 2>>"$work/vg.txt" |
        awk '/libembree3/ { gsub(",", "", $1); s += $1 } END { printf "%d", s }') ||
        cannot_measure "callgrind_annotate could not read $scene --spp $spp's profile" "$work/vg.txt"
    printf -v "$var" '%s' "$n"
    printf -v "$evar" '%s' "$e"
}

status=0 r_lo='' r_hi='' i_lo='' i_hi='' e_lo='' e_hi=''
for render in "${renders[@]}"; do
    IFS='|' read -r name scene arg_text <<<"$render"
    read -r -a args <<<"$arg_text"
    command_text="restir render $scene $arg_text --spp {$spp_lo,$spp_hi}"
    rays "$scene" $spp_lo r_lo "${args[@]}"
    rays "$scene" $spp_hi r_hi "${args[@]}"
    [ "$r_hi" -gt "$r_lo" ] ||
        cannot_measure "$name: --spp $spp_hi traced $r_hi rays, --spp $spp_lo $r_lo: no difference to divide by"
    instr "$scene" $spp_lo i_lo e_lo "${args[@]}"
    instr "$scene" $spp_hi i_hi e_hi "${args[@]}"
    verdict=0
    /usr/bin/python3 - "$budget" "$name" "$command_text" "$r_lo" "$r_hi" "$i_lo" "$i_hi" "$e_lo" "$e_hi" <<'PY' || verdict=$?
import json, sys
path, name, command = sys.argv[1:4]
r_lo, r_hi, i_lo, i_hi, e_lo, e_hi = map(int, sys.argv[4:])
try:
    b = json.load(open(path))
    entry = b["renders"][name]
    budget, tolerance = float(entry["instr_per_ray"]), float(b["tolerance"])
except (OSError, ValueError, KeyError, TypeError) as e:
    print(f"test-perf: could not measure: {path}: no budget for /renders/{name} ({e!r})", file=sys.stderr)
    sys.exit(2)
if entry.get("command") != command:
    print(f"test-perf: could not measure: {path}: /renders/{name}/command is {entry.get('command')!r}, "
          f"this test runs {command!r}", file=sys.stderr)
    sys.exit(2)
per_ray = (i_hi - i_lo) / (r_hi - r_lo)
embree = (e_hi - e_lo) / (r_hi - r_lo)
limit = budget * (1.0 + tolerance)
floor = budget * (1.0 - tolerance)
verdict = "ok" if per_ray <= limit else "OVER BUDGET"
print(f"test-perf: pt {name}, {per_ray:.1f} instructions per ray ({i_hi - i_lo} instructions / "
      f"{r_hi - r_lo} rays; Embree {embree:.1f}, the rest {per_ray - embree:.1f}); "
      f"budget {budget} + {tolerance * 100:g} % = {limit:.1f}: {verdict}")
if per_ray > limit:
    print(f"test-perf: the path loop does more work per ray than {path} allows; find where with "
          f"valgrind --tool=callgrind and callgrind_annotate (docs/benchmarks.md)", file=sys.stderr)
    sys.exit(1)
if per_ray < floor:
    # The budget only holds the gain if it follows the figure down.
    print(f"test-perf: NOTICE: pt {name} is {per_ray:.1f}, below {budget} - {tolerance * 100:g} % = {floor:.1f}: "
          f"lower /renders/{name}/instr_per_ray in {path} to {per_ray:.1f}")
PY
    case $verdict in
        0) ;;
        1) status=1 ;;
        *) exit "$verdict" ;;
    esac
done
exit $status
