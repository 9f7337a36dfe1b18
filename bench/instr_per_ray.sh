#!/usr/bin/env bash
# Instructions per ray, ours vs Embree's pathtracer tutorial, counted by callgrind: unlike
# wall-clock time this does not depend on the machine's load, so it is a repeatable
# side-by-side figure of the work each renderer does per ray. Start-up (scene load, BVH build)
# cancels out: each side is run at two sample counts and only the differences are used.
# Prints one JSON object. Needs valgrind and build/bench/raycount_preload.so (bench/run.sh).
# Instructions are not time (the two programs' instructions differ in cost), so this
# complements the wall-clock ratio; it does not replace it.
set -euo pipefail
cd "$(dirname "$0")/.."
command -v valgrind >/dev/null || { echo '{"error":"valgrind not installed"}'; exit 0; }
out=build/bench/instr
mkdir -p "$out"
shim=build/bench/raycount_preload.so
peer=/usr/bin/pathtracer
model=/usr/share/doc/embree3/models/cornell_box.ecs

instr() {  # callgrind's instruction total of a command
    timeout 600 valgrind --tool=callgrind --callgrind-out-file="$out/cg.out" "$@" >/dev/null 2>"$out/vg.txt"
    grep -o 'Collected : [0-9]*' "$out/vg.txt" | awk '{print $3}'
}

# Rays: the peer's counted by the shim in plain runs (its counts are deterministic), ours from
# its own --json count (bench/run.sh checks that it equals the shim's count of our calls).
# Instructions: callgrind runs without the shim, so the wrapper's cost never enters.
peer_rays() {
    # The shim goes into the peer only (env inside timeout): a shim loaded into `timeout`
    # itself would overwrite the counts with its own zeros when it exits.
    rm -f "$out/p.json"
    timeout 600 env RAYCOUNT_OUT="$out/p.json" LD_PRELOAD=$shim $peer -c $model --size 64 64 --threads 1 \
        --benchmark 0 "$1" >/dev/null 2>&1
    /usr/bin/python3 -c "import json;print(json.load(open('$out/p.json'))['rays'])"
}
ours_rays() {  # $1 spp, then options (the random sampler's)
    local spp=$1
    shift
    build/restir render scenes/cornell-box/scene.json --spp "$spp" --size 64x64 --threads 1 --max-depth 8 "$@" \
        --json -o "$out/o.exr" | /usr/bin/python3 -c "import json,sys;print(json.load(sys.stdin)['rays'])"
}
# pt's default sampler is Sobol' (reference_pt.h); the random sampler's loop, which the tutorial's
# own random numbers compare with most directly, is measured beside it.
random=(--frames 1 --params '{"sampler":"random"}')
r1=$(peer_rays 1); r3=$(peer_rays 3)
p1=$(instr $peer -c $model --size 64 64 --threads 1 --benchmark 0 1)
p3=$(instr $peer -c $model --size 64 64 --threads 1 --benchmark 0 3)
q1=$(ours_rays 4); q3=$(ours_rays 12)
o1=$(instr build/restir render scenes/cornell-box/scene.json --spp 4 --size 64x64 --threads 1 --max-depth 8 -o "$out/o.exr")
o3=$(instr build/restir render scenes/cornell-box/scene.json --spp 12 --size 64x64 --threads 1 --max-depth 8 -o "$out/o.exr")
s1=$(ours_rays 4 "${random[@]}"); s3=$(ours_rays 12 "${random[@]}")
n1=$(instr build/restir render scenes/cornell-box/scene.json --spp 4 --size 64x64 --threads 1 --max-depth 8 "${random[@]}" -o "$out/o.exr")
n3=$(instr build/restir render scenes/cornell-box/scene.json --spp 12 --size 64x64 --threads 1 --max-depth 8 "${random[@]}" -o "$out/o.exr")
/usr/bin/python3 - "$p1" "$p3" "$r1" "$r3" "$o1" "$o3" "$q1" "$q3" "$n1" "$n3" "$s1" "$s3" <<'PY'
import json, sys
p1, p3, r1, r3, o1, o3, q1, q3, n1, n3, s1, s3 = map(int, sys.argv[1:])
peer = (p3 - p1) / (r3 - r1)
ours = (o3 - o1) / (q3 - q1)
ours_random = (n3 - n1) / (s3 - s1)
print(json.dumps({"peer_instr_per_ray": round(peer, 1), "ours_instr_per_ray": round(ours, 1),
                  "peer_over_ours": round(peer / ours, 3), "ours_random_instr_per_ray": round(ours_random, 1),
                  "ours_random_over_peer": round(ours_random / peer, 3), "peer_rays": r3 - r1, "ours_rays": q3 - q1,
                  "commands": {"peer": "pathtracer -c cornell_box.ecs --size 64 64 --threads 1 --benchmark 0 {1,3}",
                               "ours": "restir render scenes/cornell-box/scene.json --spp {4,12} --size 64x64 --threads 1 --max-depth 8",
                               "ours_random": "restir render scenes/cornell-box/scene.json --spp {4,12} --size 64x64 --threads 1 "
                                              "--max-depth 8 --frames 1 --params '{\"sampler\":\"random\"}'"}}))
PY
