#!/usr/bin/env bash
# bench/crosscheck.sh — radiometric cross-check of our reference path tracer against Blender
# Cycles on the same scene (default: the exact Cornell box). A benchmark-tier verification,
# run by hand (not by `make test`). Method and recorded numbers: docs/crosscheck.md.
#
#   bash bench/crosscheck.sh                      # 128x128, 4096 spp per renderer, 16 runs each
#   CC_SIZE=64x64 CC_SPP=1024 bash bench/crosscheck.sh   # quicker, coarser
#   bash bench/crosscheck.sh direct               # diagnostic: direct light vs closed form
#
# What it does:
#   1. installs Blender (Debian package `blender`) if missing — needs root or sudo;
#   2. checks the Cycles emission scale and one-sidedness with bench/crosscheck_cycles.py
#      --probe-emission front|back (an emitter of colour 1, strength 1 must read 1.0 from the
#      front and 0.0 from the back);
#   3. renders the scene CC_RUNS times with each renderer, independent seeds, CC_SPP/CC_RUNS
#      samples per pixel each (so each renderer gets CC_SPP in total);
#   4. compares (numpy + OpenImageIO, /usr/bin/python3): per-channel image means with standard
#      errors from the spread of the runs, their difference and its z-score, and per-pixel
#      z-scores / relative errors of the averaged images against what noise alone would give.
# Environment: CC_SCENE (scenes/cornell-box/scene.json), CC_SIZE (128x128), CC_SPP (4096),
# CC_RUNS (16), CC_MAX_DEPTH (64, both renderers), CC_THREADS (0 = all cores),
# CC_CYCLES_BOUNCES (= CC_MAX_DEPTH), CC_CYCLES_LIGHT_SAMPLING (off: see below),
# CC_OUT (build/crosscheck), CC_SKIP_RENDER=1 (re-analyse existing images only).
# Outputs in CC_OUT: cycles_K.exr, ours_K.exr, ours_K.json, logs/, report.json, report.txt,
# mean_ours.exr, mean_cycles.exr, diff.exr (ours − Cycles), z.exr (per-pixel z-scores).
set -euo pipefail
cd "$(dirname "$0")/.."

SCENE=${CC_SCENE:-scenes/cornell-box/scene.json}
SIZE=${CC_SIZE:-128x128}
SPP=${CC_SPP:-4096}
RUNS=${CC_RUNS:-16}
DEPTH=${CC_MAX_DEPTH:-64}
CYCLES_BOUNCES=${CC_CYCLES_BOUNCES:-$DEPTH}
# Cycles 3.4's next-event estimation on mesh lights loses energy here (shadow rays towards a
# light triangle are blocked by its coplanar neighbour at grazing angles; docs/crosscheck.md),
# so by default Cycles finds emitters by BSDF sampling only: slower to converge, but unbiased.
CYCLES_LS=${CC_CYCLES_LIGHT_SAMPLING:-off}
THREADS=${CC_THREADS:-0}
OUT=${CC_OUT:-build/crosscheck}
PY=/usr/bin/python3

if [[ ${1:-} == direct ]]; then
    # Diagnostic mode (Cornell box only): direct lighting alone, both renderers against the
    # closed form (Lambert's formula for a uniform polygonal emitter) on the upper back wall.
    OUT=${CC_OUT:-build/crosscheck-direct}
    RUNS=${CC_RUNS:-8}
    PER=${CC_SPP_PER_RUN:-128}
    mkdir -p "$OUT/logs"
    [[ -x build/restir ]] || make build/restir
    for ((k = 0; k < RUNS; k++)); do
        ./build/restir render "$SCENE" --method pt --spp "$PER" --size "$SIZE" --seed $((1000 + k)) --max-depth 1 \
            --threads "$THREADS" --json -o "$OUT/ours_$k.exr" > "$OUT/ours_$k.json" 2> "$OUT/logs/ours_$k.err"
        for ls in on off; do
            spp=$PER; [[ $ls == off ]] && spp=$((4 * PER))   # BSDF sampling alone is noisier
            blender -b --factory-startup -noaudio -P bench/crosscheck_cycles.py -- --scene "$SCENE" --size "$SIZE" \
                --spp "$spp" --seed $((1000 + k)) --max-bounces 0 --light-sampling $ls --threads "$THREADS" \
                --out "$OUT/cycles_ls${ls}_$k.exr" > "$OUT/logs/cycles_ls${ls}_$k.log" 2>&1
        done
        printf 'direct run %d/%d done\r' $((k + 1)) "$RUNS" >&2
    done
    echo >&2
    $PY - "$OUT" "$RUNS" "$SCENE" <<'EOF2'
import json, math, sys
import numpy as np
import OpenImageIO as oiio
out, K, scene = sys.argv[1], int(sys.argv[2]), json.load(open(sys.argv[3]))
def load(p):
    i = oiio.ImageInput.open(p)
    a = i.read_image(oiio.FLOAT)
    i.close()
    return np.asarray(a, dtype=np.float64)[..., :3]
sets = {"restir (NEE+MIS)": "ours", "Cycles, light sampling on (NEE+MIS)": "cycles_lson",
        "Cycles, light sampling off (BSDF only)": "cycles_lsoff"}
imgs = {n: np.stack([load(f"{out}/{p}_{k}.exr") for k in range(K)]) for n, p in sets.items()}
_, H, W, _ = next(iter(imgs.values())).shape
lamp = [sh for sh in scene["shapes"] if "emission" in scene["materials"][sh["material"]]]
assert len(lamp) == 1 and lamp[0]["type"] == "quad", "direct mode needs exactly one emissive quad"
V = np.array(lamp[0]["vertices"], float)
Le = np.array(scene["materials"][lamp[0]["material"]]["emission"], float)
alb = np.array(scene["materials"]["white"]["albedo"], float)
cam = scene["camera"]
assert cam["position"] == [278, 273, -800] and cam["look_at"] == [278, 273, 0], "direct mode: Cornell camera only"
t = math.tan(math.radians(cam["fov_deg"]) / 2)
ZW = 559.2                      # back wall plane; its normal is -z
S = 8                           # sub-pixel points for the footprint average
u = (np.arange(S) + 0.5) / S
def irradiance(P):              # Lambert: E = L/2 sum_i angle_i (n . unit normal of edge plane)
    E = 0.0
    for i in range(len(V)):
        a, b = V[i] - P, V[(i + 1) % len(V)] - P
        a /= np.linalg.norm(a, axis=-1, keepdims=True); b /= np.linalg.norm(b, axis=-1, keepdims=True)
        c = np.cross(a, b)
        E = E + np.arccos(np.clip((a * b).sum(-1), -1, 1)) * (c @ np.array([0, 0, -1.0])) / np.linalg.norm(c, axis=-1)
    return np.abs(0.5 * E)
rows, cols, ana = [], [], []
for j in range(H):
    for i in range(W):
        sx = (2 * (i + u[:, None]) / W - 1) * t * W / H
        sy = (1 - 2 * (j + u[None, :]) / H) * t + 0 * sx
        d = ZW - cam["position"][2]
        P = np.stack([cam["position"][0] - sx * d + 0 * sy, cam["position"][1] + sy * d, np.full(sy.shape, ZW)], -1)
        # wall seen by the camera and lit by the whole emitter: above the blocks' silhouettes
        # (y > 360 from this camera), below the ceiling, between the side walls
        if P[..., 1].min() > 360 and P[..., 1].max() < 548.0 and P[..., 0].min() > 1 and P[..., 0].max() < 548:
            rows.append(j); cols.append(i); ana.append(irradiance(P).mean())
rows, cols = np.array(rows), np.array(cols)
ref = (np.array(ana)[:, None] * alb / math.pi * Le).mean(axis=0)
print(f"direct lighting only, {len(rows)} pixels of the upper back wall (y 360..548), {K} runs each")
print(f"closed form (Lambert polygon formula, 8x8 points per pixel) mean RGB: {ref[0]:.6f} {ref[1]:.6f} {ref[2]:.6f}")
res = {}
for n, v in imgs.items():
    per = v[:, rows, cols, :].mean(axis=1) / ref - 1            # K,3 relative errors
    m, se = per.mean(axis=0), per.std(axis=0, ddof=1) / math.sqrt(K)
    res[n] = {"relative_rgb": m.tolist(), "stderr_rgb": se.tolist()}
    print(f"  {n:42} {100 * m[1]:+7.3f}% ± {100 * se[1]:.3f}%  (G; R {100 * m[0]:+.3f}%, B {100 * m[2]:+.3f}%)")
json.dump({"pixels": int(len(rows)), "closed_form_rgb": ref.tolist(), "relative": res}, open(f"{out}/direct.json", "w"), indent=1)
EOF2
    exit 0
fi

if (( SPP % RUNS != 0 )); then echo "crosscheck: CC_SPP ($SPP) must be a multiple of CC_RUNS ($RUNS)" >&2; exit 2; fi
if (( RUNS < 2 )); then echo "crosscheck: CC_RUNS must be >= 2 (the noise estimate needs it)" >&2; exit 2; fi
PER=$(( SPP / RUNS ))

as_root() { if [[ $(id -u) == 0 ]]; then "$@"; else sudo "$@"; fi; }
need_pkgs=()
command -v blender >/dev/null || need_pkgs+=(blender)
$PY -c 'import numpy' 2>/dev/null || need_pkgs+=(python3-numpy)
$PY -c 'import OpenImageIO' 2>/dev/null || need_pkgs+=(python3-openimageio)
if (( ${#need_pkgs[@]} )); then
    echo "crosscheck: installing ${need_pkgs[*]} (apt-get)" >&2
    as_root apt-get update
    as_root env DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends "${need_pkgs[@]}"
fi
[[ -f $SCENE ]] || { echo "crosscheck: scene $SCENE not found" >&2; exit 2; }
[[ -x build/restir ]] || make build/restir

mkdir -p "$OUT/logs"
BLENDER=(blender -b --factory-startup -noaudio -P bench/crosscheck_cycles.py --)
[[ ${CC_SKIP_RENDER:-0} == 1 && -f $OUT/meta.txt ]] || {
    echo "date: $(date -u +%Y-%m-%dT%H:%M:%SZ)"
    echo "host: $(uname -srm), $(nproc) cores, $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2- | sed 's/^ //')"
    echo "blender: $(blender --version 2>/dev/null | head -1)"
    echo "restird: $(git rev-parse --short HEAD 2>/dev/null || echo '?')$(git diff --quiet HEAD -- renderer server 2>/dev/null || echo ' (+ uncommitted changes)')"
    echo "scene: $SCENE, size $SIZE, $SPP spp per renderer as $RUNS runs x $PER spp, max depth $DEPTH (Cycles max bounces $CYCLES_BOUNCES, Cycles light sampling $CYCLES_LS)"
} > "$OUT/meta.txt"

if [[ ${CC_SKIP_RENDER:-0} != 1 ]]; then
    # Step 2: Cycles emission scale / one-sidedness probe.
    for side in front back; do
        "${BLENDER[@]}" --probe-emission $side --size 16x16 --spp 4 --out "$OUT/probe_$side.exr" \
            > "$OUT/logs/probe_$side.log" 2>&1 || { echo "crosscheck: Blender probe failed, see $OUT/logs/probe_$side.log" >&2; exit 1; }
    done
    $PY - "$OUT" <<'EOF'
import sys, numpy as np, OpenImageIO as oiio
out = sys.argv[1]
for side, want in (("front", 1.0), ("back", 0.0)):
    a = oiio.ImageInput.open(f"{out}/probe_{side}.exr").read_image(oiio.FLOAT)[..., :3]
    lo, hi = float(a.min()), float(a.max())
    print(f"probe: Cycles emission colour 1 strength 1, {side} face: pixels in [{lo:.6g}, {hi:.6g}] (want {want})")
    if abs(lo - want) > 1e-5 or abs(hi - want) > 1e-5:
        sys.exit("crosscheck: Cycles emission probe failed: the Cycles setup does not give radiance = colour")
EOF

    # Step 3: the renders. Cycles first, then ours, each run with its own seed.
    t0=$(date +%s.%N)
    for ((k = 0; k < RUNS; k++)); do
        "${BLENDER[@]}" --scene "$SCENE" --size "$SIZE" --spp "$PER" --seed $((1000 + k)) \
            --max-bounces "$CYCLES_BOUNCES" --light-sampling "$CYCLES_LS" --threads "$THREADS" --out "$OUT/cycles_$k.exr" \
            > "$OUT/logs/cycles_$k.log" 2>&1 || { echo "crosscheck: Cycles run $k failed, see $OUT/logs/cycles_$k.log" >&2; exit 1; }
        printf 'cycles run %d/%d done\r' $((k + 1)) "$RUNS" >&2
    done
    t1=$(date +%s.%N)
    for ((k = 0; k < RUNS; k++)); do
        ./build/restir render "$SCENE" --method pt --spp "$PER" --size "$SIZE" --seed $((1000 + k)) \
            --max-depth "$DEPTH" --threads "$THREADS" --json -o "$OUT/ours_$k.exr" \
            > "$OUT/ours_$k.json" 2> "$OUT/logs/ours_$k.err" || { echo "crosscheck: restir run $k failed, see $OUT/logs/ours_$k.err" >&2; exit 1; }
        printf 'restir run %d/%d done\r' $((k + 1)) "$RUNS" >&2
    done
    t2=$(date +%s.%N)
    echo >&2
    echo "wall: cycles $(echo "$t1 - $t0" | bc) s, restir $(echo "$t2 - $t1" | bc) s (both including process start-up)" >> "$OUT/meta.txt"
fi

# Step 4: the comparison.
$PY - "$OUT" "$RUNS" <<'EOF'
import json, math, sys
import numpy as np
import OpenImageIO as oiio

np.seterr(divide="ignore", invalid="ignore")  # masked pixels are dropped explicitly below
out, K = sys.argv[1], int(sys.argv[2])
CH = ("R", "G", "B")
LUM = np.array([0.2126, 0.7152, 0.0722])   # Rec. 709 luminance of linear RGB


def load(path):
    inp = oiio.ImageInput.open(path)
    if inp is None:
        sys.exit(f"crosscheck: cannot read {path}: {oiio.geterror()}")
    spec = inp.spec()
    names = [spec.channelnames[i] for i in range(spec.nchannels)]
    a = inp.read_image(oiio.FLOAT)
    inp.close()
    idx = [names.index(c) for c in CH]
    return np.ascontiguousarray(np.asarray(a, dtype=np.float64)[..., idx])


def save(path, img):
    h, w, c = img.shape
    o = oiio.ImageOutput.create(path)
    ok = o.open(path, oiio.ImageSpec(w, h, c, oiio.FLOAT)) and \
        o.write_image(np.ascontiguousarray(img, dtype=np.float32))
    o.close()
    if not ok:
        sys.exit(f"crosscheck: cannot write {path}: {o.geterror()}")


def t_stats(nu):
    """E[T^2] and P(|T| > 3) of a Student t with nu degrees of freedom (numerically)."""
    x = np.linspace(3.0, 3000.0, 2_000_001)
    c = math.exp(math.lgamma((nu + 1) / 2) - math.lgamma(nu / 2)) / math.sqrt(nu * math.pi)
    pdf = c * (1 + x * x / nu) ** (-(nu + 1) / 2)
    tail = 2 * float(np.sum((pdf[1:] + pdf[:-1]) * 0.5 * np.diff(x)))
    return (nu / (nu - 2) if nu > 2 else float("inf")), tail


imgs = {}
for r in ("ours", "cycles"):
    imgs[r] = np.stack([load(f"{out}/{r}_{k}.exr") for k in range(K)])  # K,H,W,3
if imgs["ours"].shape != imgs["cycles"].shape:
    sys.exit(f"crosscheck: shapes differ: {imgs['ours'].shape} vs {imgs['cycles'].shape}")
_, H, W, _ = imgs["ours"].shape
nonfinite = {r: int((~np.isfinite(v)).sum()) for r, v in imgs.items()}
for r in imgs:
    imgs[r] = np.nan_to_num(imgs[r], nan=0.0, posinf=0.0, neginf=0.0)

rep = {"size": [W, H], "runs": K, "nonfinite_values": nonfinite}
M, V, m, se = {}, {}, {}, {}
for r, v in imgs.items():
    M[r] = v.mean(axis=0)                          # averaged image
    V[r] = v.var(axis=0, ddof=1) / K               # per-pixel variance of the average
    run_means = v.mean(axis=(1, 2))                # K,3
    run_means = np.concatenate([run_means, run_means @ LUM[:, None]], axis=1)  # + luminance
    m[r] = run_means.mean(axis=0)
    se[r] = run_means.std(axis=0, ddof=1) / math.sqrt(K)
    rep[r] = {"mean_rgbY": m[r].tolist(), "stderr_rgbY": se[r].tolist(),
              "run_means_rgbY": run_means.tolist()}
    save(f"{out}/mean_{r}.exr", M[r])

# Directly visible emitter pixels are identical in expectation and dominate the image mean;
# the same statistics over the other pixels ("surfaces": mean <= 1 in every channel in both).
surf = (M["ours"].max(axis=2) <= 1.0) & (M["cycles"].max(axis=2) <= 1.0)
for r, v in imgs.items():
    rm = v[:, surf, :].mean(axis=1)
    rm = np.concatenate([rm, rm @ LUM[:, None]], axis=1)
    m[r + "_surf"] = rm.mean(axis=0)
    se[r + "_surf"] = rm.std(axis=0, ddof=1) / math.sqrt(K)
    rep[r]["surfaces_mean_rgbY"] = m[r + "_surf"].tolist()
    rep[r]["surfaces_stderr_rgbY"] = se[r + "_surf"].tolist()
rep["surfaces_pixels"] = int(surf.sum())
ds = m["ours_surf"] - m["cycles_surf"]
seds = np.sqrt(se["ours_surf"] ** 2 + se["cycles_surf"] ** 2)
rep["surfaces_mean_diff"] = {"ours_minus_cycles_rgbY": ds.tolist(), "stderr_rgbY": seds.tolist(),
                             "z_rgbY": (ds / seds).tolist(), "relative_rgbY": (ds / m["cycles_surf"]).tolist(),
                             "relative_stderr_rgbY": (seds / m["cycles_surf"]).tolist()}

d = m["ours"] - m["cycles"]
sed = np.sqrt(se["ours"] ** 2 + se["cycles"] ** 2)
rel = d / m["cycles"]
rel_se = sed / m["cycles"]  # first order; the relative error of the denominator is negligible
rep["mean_diff"] = {"ours_minus_cycles_rgbY": d.tolist(), "stderr_rgbY": sed.tolist(),
                    "z_rgbY": (d / sed).tolist(), "relative_rgbY": rel.tolist(),
                    "relative_stderr_rgbY": rel_se.tolist()}

# Orientation: the red wall must be on the same side in both (ours: left).
def red_side(img):
    wcol = max(1, W // 10)
    l = img[:, :wcol, 0].mean() - img[:, :wcol, 1].mean()
    r_ = img[:, -wcol:, 0].mean() - img[:, -wcol:, 1].mean()
    return "left" if l > r_ else "right"
rep["red_side"] = {r: red_side(M[r]) for r in M}

# Per-pixel comparison of the averaged images.
diff = M["ours"] - M["cycles"]
var = V["ours"] + V["cycles"]
ok = var > 0
z = np.where(ok, diff / np.sqrt(np.where(ok, var, 1.0)), 0.0)
save(f"{out}/diff.exr", diff)
save(f"{out}/z.exr", z)
nu = 2 * (K - 1)  # Welch dof when both variances are alike; the exact value varies per pixel
e_z2, p3 = t_stats(nu)
zz = z[ok.all(axis=2)]
pix = {
    "pixels_compared": int(zz.shape[0]),
    "z_mean_rgb": zz.mean(axis=0).tolist(),
    "z_rms_rgb": np.sqrt((zz ** 2).mean(axis=0)).tolist(),
    "frac_abs_z_gt_3_rgb": (np.abs(zz) > 3).mean(axis=0).tolist(),
    "expected_if_equal": {"z_mean": 0.0, "z_rms": math.sqrt(e_z2), "frac_abs_z_gt_3": p3, "t_dof": nu},
}
# Relative errors: on luminance, over pixels with a signal.
Yo, Yc = M["ours"] @ LUM, M["cycles"] @ LUM
# (luminance of each run first: the channels of one path are correlated)
VY = sum((imgs[r] @ LUM).var(axis=0, ddof=1) / K for r in imgs)
sig = Yc > 1e-3 * Yc.max()
ape = np.abs(Yo - Yc)[sig] / Yc[sig]
pix["luminance"] = {
    "pixels": int(sig.sum()),
    "mape": float(ape.mean()),
    "median_ape": float(np.median(ape)),
    "rms_rel_diff": float(np.sqrt((((Yo - Yc) / Yc)[sig] ** 2).mean())),
    "rms_rel_noise_expected": float(np.sqrt((VY / Yc ** 2)[sig].mean())),
}
n2 = (((Yo - Yc) ** 2 - VY) / Yc ** 2)[sig].mean()
pix["luminance"]["rms_rel_excess_over_noise"] = float(math.sqrt(n2)) if n2 > 0 else 0.0
# 8x8-pixel blocks: much less noise per value, shows spatially structured differences.
b = 8 if H % 8 == 0 and W % 8 == 0 else 1
def blocks(a):
    return a.reshape(H // b, b, W // b, b).mean(axis=(1, 3))
BYo, BYc = blocks(Yo), blocks(Yc)
BV = sum(np.stack([blocks(y) for y in imgs[r] @ LUM]).var(axis=0, ddof=1) / K for r in imgs)
bz = (BYo - BYc) / np.sqrt(BV)
worst = np.dstack(np.unravel_index(np.argsort(-np.abs(bz), axis=None)[:5], bz.shape))[0]
pix["blocks"] = {"block_px": b, "count": int(bz.size), "z_rms": float(np.sqrt((bz ** 2).mean())),
                 "frac_abs_z_gt_3": float((np.abs(bz) > 3).mean()),
                 "worst": [{"x0": int(j * b), "y0": int(i * b), "ours_Y": float(BYo[i, j]),
                            "cycles_Y": float(BYc[i, j]), "z": float(bz[i, j])} for i, j in worst]}
rep["per_pixel"] = pix
json.dump(rep, open(f"{out}/report.json", "w"), indent=1)

# The printed report.
L = []
L.append(open(f"{out}/meta.txt").read().rstrip())
L.append(f"red wall side: ours {rep['red_side']['ours']}, cycles {rep['red_side']['cycles']}"
         + ("" if rep["red_side"]["ours"] == rep["red_side"]["cycles"] else "   <-- MIRRORED"))
if any(nonfinite.values()):
    L.append(f"non-finite values (zeroed): {nonfinite}")
L.append("")
L.append("image mean (± standard error from the spread of the runs)")
L.append(f"{'':6} {'ours':>22} {'cycles':>22} {'ours-cycles':>22} {'z':>6} {'relative':>18}")
for i, c in enumerate(("R", "G", "B", "Y")):
    L.append(f"{c:6} {m['ours'][i]:>11.6f} ± {se['ours'][i]:<8.6f} {m['cycles'][i]:>11.6f} ± {se['cycles'][i]:<8.6f} "
             f"{d[i]:>+11.6f} ± {sed[i]:<8.6f} {d[i] / sed[i]:>+6.2f} {100 * rel[i]:>+8.3f}% ± {100 * rel_se[i]:.3f}%")
L.append(f"same, over the {rep['surfaces_pixels']} pixels not showing the emitter (mean <= 1 in both images)")
for i, c in enumerate(("R", "G", "B", "Y")):
    a_, b_ = m["ours_surf"][i], m["cycles_surf"][i]
    L.append(f"{c:6} {a_:>11.6f} ± {se['ours_surf'][i]:<8.6f} {b_:>11.6f} ± {se['cycles_surf'][i]:<8.6f} "
             f"{ds[i]:>+11.6f} ± {seds[i]:<8.6f} {ds[i] / seds[i]:>+6.2f} {100 * ds[i] / b_:>+8.3f}% ± {100 * seds[i] / b_:.3f}%")
L.append("")
L.append(f"per pixel ({pix['pixels_compared']} px; z = (ours - cycles) / noise sd of the difference,"
         f" noise from {K} runs each; if equal: z ~ Student t, {nu} dof)")
L.append(f"  z mean  R G B: {' '.join(f'{v:+.3f}' for v in pix['z_mean_rgb'])}   (expect 0 ± {1 / math.sqrt(pix['pixels_compared']):.3f})")
L.append(f"  z rms   R G B: {' '.join(f'{v:.3f}' for v in pix['z_rms_rgb'])}   (expect {math.sqrt(e_z2):.3f})")
L.append(f"  |z|>3   R G B: {' '.join(f'{100 * v:.2f}%' for v in pix['frac_abs_z_gt_3_rgb'])}   (expect {100 * p3:.2f}%)")
lu = pix["luminance"]
L.append(f"  luminance, {lu['pixels']} px with signal: MAPE {100 * lu['mape']:.2f}%, median APE {100 * lu['median_ape']:.2f}%,"
         f" RMS rel. diff {100 * lu['rms_rel_diff']:.2f}% vs {100 * lu['rms_rel_noise_expected']:.2f}% expected from noise"
         f" -> excess {100 * lu['rms_rel_excess_over_noise']:.2f}%")
bl = pix["blocks"]
L.append(f"  {bl['block_px']}x{bl['block_px']} blocks ({bl['count']}): luminance z rms {bl['z_rms']:.3f}, |z|>3 {100 * bl['frac_abs_z_gt_3']:.2f}%;"
         f" worst: " + ", ".join(f"({w['x0']},{w['y0']}) z {w['z']:+.1f}" for w in bl["worst"][:3]))
txt = "\n".join(L)
open(f"{out}/report.txt", "w").write(txt + "\n")
print(txt)
EOF
