#!/usr/bin/env bash
# bench/run.sh — `make bench`: throughput of our path tracer vs Embree's pathtracer tutorial.
#
# Benchmarks are not tests: nothing here passes or fails on a timing.
# What it does, in one run, with the same thread count on both sides:
#   1. builds build/bench/raycount_preload.so (LD_PRELOAD ray counter for the peer) and, when
#      bench/exr_encode.c exists, build/bench/exr_encode; it builds nothing else (the Makefile
#      builds build/restir before calling this script);
#   2. counts the peer's ray queries for the 5 warm-up frames alone (`--benchmark 5 0` under
#      the shim), to subtract them;
#   3. REPS repetitions, alternating which side goes first:
#        peer  `pathtracer ... --benchmark 5 20`          its printed (filtered) summary
#        peer  `pathtracer ... --benchmark 25 0`          every frame's fps printed: exact times
#        peer  the same under the shim (order alternates) counts (deterministic: re-checked
#                                                         every time) + the shim's overhead
#        ours  `build/restir render ... --method pt --json`
#   4. runs build/bench/exr_encode if it was built;
#   5. writes build/bench/results.json and prints a Markdown table of medians.
# Environment overrides: BENCH_REPS (5), BENCH_THREADS (nproc), BENCH_DEADLINE_S (480: no new
# repetition starts unless it would end, judging by the last one, within this many seconds),
# PATHTRACER (path of the peer binary),
# OUR_SCENE (scenes/cornell-box/scene.json), OUR_SPP (20), OUR_MAX_DEPTH (8).
# See docs/benchmarks.md for the method and bench/README.md for the file map.
set -uo pipefail

cd "$(dirname "$0")/.."
ROOT=$(pwd)
OUT=build/bench
mkdir -p "$OUT/logs"

REPS=${BENCH_REPS:-5}
(( REPS >= 1 && REPS <= 50 )) || { echo "bench: BENCH_REPS must be 1..50" >&2; exit 2; }
THREADS=${BENCH_THREADS:-$(nproc)}
DEADLINE_S=${BENCH_DEADLINE_S:-480}
SIZE=512
WARMUP=5
FRAMES=20
MODELS=/usr/share/doc/embree3/models
PEER_SCENE=$MODELS/cornell_box.ecs
OUR_SCENE=${OUR_SCENE:-scenes/cornell-box/scene.json}
OUR_SPP=${OUR_SPP:-$FRAMES}        # the peer traces 1 sample/pixel per frame, FRAMES frames
OUR_MAX_DEPTH=${OUR_MAX_DEPTH:-8}  # the peer's default --max-path-length
OUR_BIN=build/restir
SHIM=$OUT/raycount_preload.so
START=$SECONDS
LOAD_START=$(cut -d' ' -f1-3 /proc/loadavg)

log() { printf 'bench: %s\n' "$*" >&2; }

# ---- peer binary --------------------------------------------------------------------------
PATHTRACER=${PATHTRACER:-}
if [ -z "$PATHTRACER" ]; then
  PATHTRACER=$(dpkg -L embree-tools 2>/dev/null | grep -m1 '/bin/pathtracer$' || true)
  [ -n "$PATHTRACER" ] || PATHTRACER=$(command -v pathtracer || true)
fi
if [ -z "$PATHTRACER" ] || [ ! -x "$PATHTRACER" ] || [ ! -r "$PEER_SCENE" ]; then
  log "Embree's pathtracer or $PEER_SCENE not found (Debian package embree-tools); peer skipped"
  PATHTRACER=""
fi

# ---- builds (bench tools only) ------------------------------------------------------------
if ! cc -O2 -std=c17 -D_GNU_SOURCE -Wall -Wextra -fPIC -shared bench/raycount_preload.c \
      -o "$SHIM" -ldl -pthread; then
  log "could not build the ray-count shim; peer rays/s unavailable"
  SHIM=""
fi

EXR_BIN=""
if [ -f bench/exr_encode.c ]; then
  if [ -f build/obj/librenderer.a ] && \
     cc -O2 -std=c17 -D_DEFAULT_SOURCE -Irenderer bench/exr_encode.c build/obj/librenderer.a \
        -lOpenEXRCore -ldeflate -lembree3 -lassimp -lcjson -lm -pthread $(pkg-config --cflags OpenEXR) \
        -o "$OUT/exr_encode"; then
    EXR_BIN=$OUT/exr_encode
  else
    log "bench/exr_encode.c did not build (needs build/obj/librenderer.a); skipped"
  fi
fi

# ---- one run of each kind; every run's full output is kept under build/bench/logs ----------
peer_cmd() { # $1 warm-up frames, $2 benchmark frames
  echo "$PATHTRACER" -c "$PEER_SCENE" --size "$SIZE" "$SIZE" --threads "$THREADS" --benchmark "$1" "$2"
}

# CPU seconds (user + sys of the process tree) are appended to each log as "BENCH_CPU_S u s":
# they move less than wall time when other jobs share the machine, so the shim's overhead is
# judged on them as well as on fps, and rays per CPU second is reported beside rays/s.
TIMEFORMAT='BENCH_CPU_S %U %S'
run_peer() { # $1 log name, $2 warm-up, $3 frames, $4 counts file or "" (no shim)
  local cmd; cmd=$(peer_cmd "$2" "$3")
  local shim=()
  # env after timeout: only the peer process carries the shim, not `timeout` itself
  [ -n "$4" ] && shim=(env RAYCOUNT_OUT="$ROOT/$4" LD_PRELOAD="$ROOT/$SHIM")
  { time ( cd "$OUT" && timeout 120 "${shim[@]}" $cmd ) ; } > "$OUT/logs/$1.txt" 2>&1 \
    || log "peer run $1 failed (exit $?), see $OUT/logs/$1.txt"
}

OURS_OK=0
if [ -x "$OUR_BIN" ] && [ -r "$OUR_SCENE" ]; then OURS_OK=1; else
  log "$OUR_BIN or $OUR_SCENE missing: our column will read 'pending'"
fi
ours_cmd() {
  echo "$OUR_BIN" render "$OUR_SCENE" --method pt --spp "$OUR_SPP" --size "${SIZE}x${SIZE}" \
       --seed 1 --threads "$THREADS" --max-depth "$OUR_MAX_DEPTH" -o "$OUT/pt.exr" --json
}
run_ours() { # $1 log name
  [ "$OURS_OK" = 1 ] || return 0
  { time timeout 300 $(ours_cmd) > "$OUT/logs/$1.json" ; } 2> "$OUT/logs/$1.err" \
    || log "our run $1 failed (exit $?), see $OUT/logs/$1.err"
}

rm -f "$OUT"/logs/*
if [ -n "$PATHTRACER" ] && [ -n "$SHIM" ]; then
  log "counting the peer's warm-up rays ($WARMUP frames)"
  run_peer count_warmup "$WARMUP" 0 "$OUT/logs/counts_warmup.json"
fi

done_reps=0
last_rep_s=0
for ((i = 1; i <= REPS; i++)); do
  # start a repetition only if one more as long as the last still ends before the deadline
  if (( SECONDS - START + last_rep_s > DEADLINE_S )); then
    log "stopping after $done_reps repetitions: another would pass the ${DEADLINE_S}s deadline"; break
  fi
  rep_start=$SECONDS
  log "repetition $i/$REPS (threads $THREADS)"
  if (( i % 2 == 0 )); then run_ours "ours_$i"; fi
  if [ -n "$PATHTRACER" ]; then
    run_peer "peer_$i" "$WARMUP" "$FRAMES" ""
    # the same 25 frames without and with the shim, in alternating order (overhead A/B)
    if (( i % 2 == 0 )) && [ -n "$SHIM" ]; then
      run_peer "peer_shim_$i" $((WARMUP + FRAMES)) 0 "$OUT/logs/counts_$i.json"
    fi
    run_peer "peer_frames_$i" $((WARMUP + FRAMES)) 0 ""
    if (( i % 2 == 1 )) && [ -n "$SHIM" ]; then
      run_peer "peer_shim_$i" $((WARMUP + FRAMES)) 0 "$OUT/logs/counts_$i.json"
    fi
  fi
  if (( i % 2 == 1 )); then run_ours "ours_$i"; fi
  done_reps=$i
  last_rep_s=$((SECONDS - rep_start))
done

# Same definition of a ray on both sides: run ours once (4 spp) under the shim and keep both its
# own count and the shim's; results.json says whether they agree.
if [ "$OURS_OK" = 1 ] && [ -n "$SHIM" ]; then
  log "checking our ray count against the shim"
  timeout 120 env RAYCOUNT_OUT="$ROOT/$OUT/logs/counts_ours.json" LD_PRELOAD="$ROOT/$SHIM" \
    $(OUR_SPP=4 ours_cmd) > "$OUT/logs/ours_shim.json" 2> "$OUT/logs/ours_shim.err" \
    || log "our shim check failed (exit $?), see $OUT/logs/ours_shim.err"
fi

EXR_LOG=""
if [ -n "$EXR_BIN" ]; then
  log "running $EXR_BIN"
  timeout 120 "$EXR_BIN" > "$OUT/logs/exr_encode.txt" 2>&1 || log "exr_encode failed (exit $?)"
  EXR_LOG=$OUT/logs/exr_encode.txt
fi

# ---- medians, results.json, Markdown table ------------------------------------------------
export OUT THREADS SIZE WARMUP FRAMES done_reps OURS_OK EXR_LOG OUR_SPP OUR_MAX_DEPTH
export PEER_CMD="$( [ -n "$PATHTRACER" ] && peer_cmd "$WARMUP" "$FRAMES")"
export PEER_FRAMES_CMD="$( [ -n "$PATHTRACER" ] && peer_cmd $((WARMUP + FRAMES)) 0)"
export OURS_CMD="$(ours_cmd)"
export LOAD_START LOAD_END="$(cut -d' ' -f1-3 /proc/loadavg)"
export MACHINE="$(nproc) cores, $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2- | sed 's/^ *//')"
timeout 60 /usr/bin/python3 - <<'PY'
import json, os, re, statistics, datetime

out = os.environ["OUT"]; logs = os.path.join(out, "logs")
reps = int(os.environ["done_reps"]); warm = int(os.environ["WARMUP"]); frames = int(os.environ["FRAMES"])

def read(path):
    try:
        with open(path) as f: return f.read()
    except OSError: return None

def med(xs):
    xs = [x for x in xs if x is not None]
    return statistics.median(xs) if xs else None

def key(text, name):
    m = re.search(r"^%s\s+([-+0-9.eEinf]+)" % name, text or "", re.M)
    try: return float(m.group(1)) if m else None
    except ValueError: return None

def cpu(text):
    m = re.search(r"^BENCH_CPU_S ([0-9.]+) ([0-9.]+)", text or "", re.M)
    return float(m.group(1)) + float(m.group(2)) if m else None

def frame_times(text):
    """Seconds of the timed frames (warm .. warm+frames-1) of a `--benchmark 25 0` log, where
    every frame is printed as "frame [  k /  25]:   5.0213 fps (skipped)"; None if incomplete."""
    fps = {int(k): float(v) for k, v in
           re.findall(r"frame \[\s*(\d+) /\s*\d+\]:\s*([0-9.]+) fps", text or "")}
    ts = [fps.get(k) for k in range(warm, warm + frames)]
    return [1.0 / f for f in ts] if ts and all(ts) else None

def counts(path):
    t = read(path)
    try: return json.loads(t) if t else None
    except ValueError: return None

warm_counts = counts(os.path.join(logs, "counts_warmup.json"))
rows = []
for i in range(1, reps + 1):
    r = {"rep": i}
    p = read(os.path.join(logs, f"peer_{i}.txt"))
    r["peer_avg_fps_filtered"] = key(p, "BENCHMARK_RENDER_AVG")
    r["peer_self_mrays_per_s"] = key(p, "BENCHMARK_RENDER_MRAYPS_AVG")
    r["peer_cpu_s"] = cpu(p)
    fr = read(os.path.join(logs, f"peer_frames_{i}.txt"))
    r["peer_frame_times_s"] = frame_times(fr)
    r["peer_bench_time_s"] = sum(r["peer_frame_times_s"]) if r["peer_frame_times_s"] else None
    r["peer_frames_cpu_s"] = cpu(fr)
    s = read(os.path.join(logs, f"peer_shim_{i}.txt"))
    r["peer_shim_frame_times_s"] = frame_times(s)
    r["peer_shim_bench_time_s"] = (sum(r["peer_shim_frame_times_s"])
                                   if r["peer_shim_frame_times_s"] else None)
    r["peer_shim_cpu_s"] = cpu(s)
    c = counts(os.path.join(logs, f"counts_{i}.json"))
    r["peer_rays_total"] = c["rays"] if c else None
    if c and warm_counts:
        r["peer_bench_rays"] = c["rays"] - warm_counts["rays"]
        r["peer_bench_isect"] = c["intersect_rays"] - warm_counts["intersect_rays"]
        r["peer_bench_occl"] = c["occluded_rays"] - warm_counts["occluded_rays"]
    o = read(os.path.join(logs, f"ours_{i}.json"))
    try:
        oj = json.loads(o.strip().splitlines()[-1]) if o and o.strip() else None
    except ValueError:
        oj = None
    r["ours_cpu_s"] = cpu(read(os.path.join(logs, f"ours_{i}.err")))
    if oj:
        r["ours"] = oj
        r["ours_rays_per_s"] = oj.get("rays_per_s")
        if oj.get("rays") and oj.get("time_ms"):
            r["ours_rays_per_s_check"] = oj["rays"] / (oj["time_ms"] / 1000.0)
        if oj.get("rays") and r["ours_cpu_s"]:
            r["ours_rays_per_cpu_s"] = oj["rays"] / r["ours_cpu_s"]
    rows.append(r)

# Per repetition: the peer's rates (rays of the timed frames from the shim run, time from the
# uninstrumented per-frame run) and ours / peer within the same repetition.
for r in rows:
    if r.get("peer_bench_rays") and r.get("peer_bench_time_s"):
        r["peer_rays_per_s"] = r["peer_bench_rays"] / r["peer_bench_time_s"]
    if r.get("peer_rays_total") and r.get("peer_frames_cpu_s"):
        r["peer_rays_per_cpu_s"] = r["peer_rays_total"] / r["peer_frames_cpu_s"]
    if r.get("ours_rays_per_s") and r.get("peer_rays_per_s"):
        r["ratio_rays_per_s"] = r["ours_rays_per_s"] / r["peer_rays_per_s"]
    if r.get("ours_rays_per_cpu_s") and r.get("peer_rays_per_cpu_s"):
        r["ratio_rays_per_cpu_s"] = r["ours_rays_per_cpu_s"] / r["peer_rays_per_cpu_s"]

def spread(name):
    xs = [r[name] for r in rows if r.get(name) is not None]
    return [min(xs), max(xs)] if xs else None

bench_rays = [r.get("peer_bench_rays") for r in rows if r.get("peer_bench_rays") is not None]
deterministic = len(set(bench_rays)) == 1 if bench_rays else None
R = med(bench_rays)
peer_time = med([r.get("peer_bench_time_s") for r in rows])
# Load-robust secondary figure: all rays of the `--benchmark 25 0` process (the same frames as
# warm-up + timed, so the same count as the shim run) per CPU second of that whole process.
all_rays = med([r.get("peer_rays_total") for r in rows])
peer_rays_per_cpu_s = med([all_rays / r["peer_frames_cpu_s"] for r in rows
                           if all_rays and r.get("peer_frames_cpu_s")])
fps_plain = med([r.get("peer_avg_fps_filtered") for r in rows])
# Shim overhead: the same `--benchmark 25 0` process without / with the shim, run back to back.
def ratio(a, b): return (b / a - 1.0) if a and b else None
plain_frames = [t for r in rows for t in (r.get("peer_frame_times_s") or [])]
shim_frames = [t for r in rows for t in (r.get("peer_shim_frame_times_s") or [])]
cpu_plain = med([r.get("peer_frames_cpu_s") for r in rows])
cpu_shim = med([r.get("peer_shim_cpu_s") for r in rows])
overhead = {
    "timed_frames_time_s": [peer_time, med([r.get("peer_shim_bench_time_s") for r in rows])],
    "median_frame_s": [med(plain_frames), med(shim_frames)],
    "fastest_frame_s": [min(plain_frames) if plain_frames else None,
                        min(shim_frames) if shim_frames else None],
    "process_cpu_s": [cpu_plain, cpu_shim],
}
overhead = {k: {"without": v[0], "with": v[1], "overhead": ratio(v[0], v[1])}
            for k, v in overhead.items()}
res = {
    "date": datetime.datetime.now().astimezone().isoformat(timespec="seconds"),
    "machine": os.environ["MACHINE"],
    "loadavg_start": os.environ["LOAD_START"], "loadavg_end": os.environ["LOAD_END"],
    "threads": int(os.environ["THREADS"]),
    "repetitions": reps, "size": [int(os.environ["SIZE"])] * 2,
    "peer": {
        "command": os.environ["PEER_CMD"], "frames_command": os.environ["PEER_FRAMES_CMD"],
        "warmup_frames": warm, "benchmark_frames": frames,
        "counts_deterministic": deterministic,
        "warmup_counts": warm_counts,
        "bench_rays": R,
        "bench_time_s_median": peer_time,
        "rays_per_s": (R / peer_time) if R and peer_time else None,
        "rays_per_s_from_filtered_fps": (R / frames * fps_plain) if R and fps_plain else None,
        "self_reported_rays_per_s": (med([r.get("peer_self_mrays_per_s") for r in rows]) or 0) * 1e6 or None,
        "rays_per_cpu_s": peer_rays_per_cpu_s,
        "rays_per_s_range": spread("peer_rays_per_s"),
        "rays_per_cpu_s_range": spread("peer_rays_per_cpu_s"),
        "avg_fps_filtered_median": fps_plain,
        "shim_overhead": overhead,
    },
    "ours": None,
    "runs": rows,
}
if os.environ.get("OURS_OK") == "1" and any(r.get("ours_rays_per_s") for r in rows):
    res["ours"] = {
        "command": os.environ["OURS_CMD"],
        "rays_per_s": med([r.get("ours_rays_per_s") for r in rows]),
        "rays_per_s_check": med([r.get("ours_rays_per_s_check") for r in rows]),
        "rays_per_cpu_s": med([r.get("ours_rays_per_cpu_s") for r in rows]),
        "rays_per_s_range": spread("ours_rays_per_s"),
        "rays_per_cpu_s_range": spread("ours_rays_per_cpu_s"),
        "ratio_rays_per_s_median": med([r.get("ratio_rays_per_s") for r in rows]),
        "ratio_rays_per_s_range": spread("ratio_rays_per_s"),
        "ratio_rays_per_cpu_s_median": med([r.get("ratio_rays_per_cpu_s") for r in rows]),
        "ratio_rays_per_cpu_s_range": spread("ratio_rays_per_cpu_s"),
        "time_ms": med([r["ours"].get("time_ms") for r in rows if r.get("ours")]),
        "rays": med([r["ours"].get("rays") for r in rows if r.get("ours")]),
    }
oc = counts(os.path.join(logs, "counts_ours.json"))
ot = read(os.path.join(logs, "ours_shim.json"))
try:
    oj = json.loads(ot.strip().splitlines()[-1]) if ot and ot.strip() else None
except ValueError:
    oj = None
if oc and oj:
    res["ours_count_check"] = {
        "reported": {k: oj.get(k) for k in ("rays", "rays_intersect", "rays_occluded")},
        "counted_by_shim": {"rays": oc["rays"], "rays_intersect": oc["intersect_rays"],
                            "rays_occluded": oc["occluded_rays"]},
        "equal": oj.get("rays") == oc["rays"] and oj.get("rays_intersect") == oc["intersect_rays"]
                 and oj.get("rays_occluded") == oc["occluded_rays"],
    }
exr = os.environ.get("EXR_LOG")
if exr:
    t = read(exr) or ""
    parsed = []
    for line in t.splitlines():
        try: parsed.append(json.loads(line))
        except ValueError: pass
    res["exr_encode"] = parsed if parsed else t
with open(os.path.join(out, "results.json"), "w") as f:
    json.dump(res, f, indent=2)

def fmt(x, scale=1e6, unit="M"):
    return "pending" if x is None else f"{x / scale:.2f} {unit}"
def fmtr(x, rng):  # median (min–max over the repetitions)
    if x is None: return "pending"
    return fmt(x) + (f" ({rng[0] / 1e6:.2f}–{rng[1] / 1e6:.2f})" if rng else "")
p, o = res["peer"], res["ours"]
print()
print(f"PT throughput, Cornell box {res['size'][0]}x{res['size'][1]}, {res['threads']} threads, "
      f"median of {reps} side-by-side runs ({res['date']}, {res['machine']}, "
      f"load average {res['loadavg_start']} at start, {res['loadavg_end']} at end)")
print()
print("| | Embree pathtracer (peer) | restird pt (ours) |")
print("|---|---|---|")
print(f"| rays/s (all benchmark frames) | {fmtr(p['rays_per_s'], p['rays_per_s_range'])} | "
      f"{fmtr(o and o['rays_per_s'], o and o['rays_per_s_range'])} |")
print(f"| rays/s (peer's filtered avg fps) | {fmt(p['rays_per_s_from_filtered_fps'])} | n/a |")
print(f"| rays/s (peer's own MRAYPS) | {fmt(p['self_reported_rays_per_s'])} | n/a |")
print(f"| rays per CPU second (whole process) | {fmtr(p['rays_per_cpu_s'], p['rays_per_cpu_s_range'])} | "
      f"{fmtr(o and o['rays_per_cpu_s'], o and o['rays_per_cpu_s_range'])} |")
print(f"| rays traced | {fmt(R)} ({frames} frames) | {fmt(o and o['rays'])} |")
peer_ms = "pending" if peer_time is None else f"{peer_time * 1e3:.0f} ms"
ours_ms = "pending" if not o or o["time_ms"] is None else f"{o['time_ms']:.0f} ms"
print(f"| time of those rays | {peer_ms} | {ours_ms} |")
if o and p["rays_per_s"] and o["rays_per_s"]:
    cpu_ratio = (f", {o['rays_per_cpu_s'] / p['rays_per_cpu_s']:.2f}x per CPU second"
                 if o["rays_per_cpu_s"] and p["rays_per_cpu_s"] else "")
    print(f"| ours / peer (ratio of medians) | | {o['rays_per_s'] / p['rays_per_s']:.2f}x rays/s{cpu_ratio} |")
    rr, rc = o["ratio_rays_per_s_range"], o["ratio_rays_per_cpu_s_range"]
    if o["ratio_rays_per_s_median"]:
        print(f"| ours / peer (median of per-repetition ratios) | | "
              f"{o['ratio_rays_per_s_median']:.2f}x rays/s ({rr[0]:.2f}–{rr[1]:.2f})"
              + (f", {o['ratio_rays_per_cpu_s_median']:.2f}x per CPU second ({rc[0]:.2f}–{rc[1]:.2f})"
                 if o["ratio_rays_per_cpu_s_median"] else "") + " |")
def pct(x): return "n/a" if x is None else f"{x * 100:+.1f} %"
def ms(x): return "n/a" if x is None else f"{x * 1e3:.1f}"
print()
print(f"shim overhead on the peer (`--benchmark {warm + frames} 0` without / with the shim, "
      f"back to back): " + "; ".join(
          f"{k.replace('_s', '').replace('_', ' ')} {ms(v['without'])} / {ms(v['with'])} ms "
          f"({pct(v['overhead'])})" for k, v in overhead.items()))
print(f"peer ray counts identical in every run: {deterministic}")
if res.get("ours_count_check"):
    occ = res["ours_count_check"]
    print(f"our reported ray count vs the shim's count of our Embree calls (4 spp): "
          f"{occ['reported']['rays']} vs {occ['counted_by_shim']['rays']} "
          f"({'equal' if occ['equal'] else 'DIFFERENT'})")
for e in (res.get("exr_encode") if isinstance(res.get("exr_encode"), list) else []):
    print(f"EXR encode {e.get('width')}x{e.get('height')} {e.get('pixel')} {e.get('channels')} "
          f"(median of {e.get('runs')}): ZIP1 {e.get('zip1_ms')} ms, PIZ {e.get('piz_ms')} ms, "
          f"NONE {e.get('none_ms')} ms")
print(f"results: {os.path.join(out, 'results.json')}")
PY
log "done in $((SECONDS - START)) s"
