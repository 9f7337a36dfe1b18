#!/usr/bin/python3
"""An independent model of the direct-light estimator that bench/direct_light_cycles.py measures,
on the Cornell box's upper back wall (no occluders between it and the light): next-event
estimation picks one of the light quad's two triangles with probability 1/2 and a direction
exactly uniform in its solid angle (rejection from uniform points by area), the BSDF sample is
cosine-weighted, the two are weighed by the power heuristic; the luminance of white's albedo times
the light's radiance. Prints, per pixel, the model's mean and variance at the pixel's centre and
with the position uniform in the pixel, next to the measured ones from a --maps file of
bench/direct_light_cycles.py (pt's variance should match the jittered model's; Cycles' is taken
with its sample offset of 1, so jittered too).

Usage: /usr/bin/python3 bench/direct_light_model.py MAPS.npz [--samples 400000] [--setting solid_angle]

Environment: NumPy only; about a minute for the default pixels. Geometry from
scenes/cornell-box/scene.json (light quad, camera), hard-coded here for the back wall z = 559.2."""
import argparse

import numpy as np

CAMERA, TAN_HALF_FOV = np.array([278, 273, -800.0]), np.tan(np.radians(39.3077 / 2))
QUAD = np.array([[343, 548, 227], [343, 548, 332], [213, 548, 332], [213, 548, 227.0]])
TRIANGLES = [QUAD[[0, 1, 2]], QUAD[[0, 2, 3]]]   # the quad's triangulation, as in both renderers
SCALE = float(np.array([0.2126, 0.7152, 0.0722]) @ (np.array([0.725, 0.71, 0.68]) * np.array([17, 12, 4.0])))
PIXELS = [(14, 31), (16, 20), (16, 43), (20, 20), (20, 31), (20, 43), (24, 16), (24, 31), (24, 47), (26, 20), (26, 43)]


def solid_angle(p, t):
    a, b, c = t[0] - p, t[1] - p, t[2] - p
    la, lb, lc = (np.linalg.norm(v, axis=-1) for v in (a, b, c))
    dot = lambda u, v: np.einsum("...i,...i", u, v)  # noqa: E731
    return 2 * np.arctan2(np.abs(dot(a, np.cross(b, c))), la * lb * lc + dot(a, b) * lc + dot(a, c) * lb + dot(b, c) * la)


def wall_points(i, j, offsets):
    """Back-wall points of pixel (row i, column j) of 64x64 at offsets in the pixel."""
    x = (j + offsets[:, 0]) / 64 * 2 - 1
    y = 1 - (i + offsets[:, 1]) / 64 * 2
    d = np.stack([-TAN_HALF_FOV * x, TAN_HALF_FOV * y, np.ones(len(offsets))], 1)
    return CAMERA + ((559.2 - CAMERA[2]) / d[:, 2])[:, None] * d


def hits(o, d, t):
    e1, e2 = t[1] - t[0], t[2] - t[0]
    pv = np.cross(d, e2)
    det = pv @ e1
    tv = o - t[0]
    u = np.einsum("ij,ij->i", tv, pv) / det
    q = np.cross(tv, e1)
    v = np.einsum("ij,ij->i", d, q) / det
    return (u >= 0) & (v >= 0) & (u + v <= 1) & ((q @ e2) / det > 0)


def uniform_solid_angle(rng, p, t):
    """Unit directions uniform in the solid angle of triangle t from each point p: uniform points by
    area accepted with probability (cos / d^2) over its bound at the triangle's nearest box point."""
    out, todo = np.empty_like(p), np.arange(len(p))
    lo, hi = t.min(0), t.max(0)
    while len(todo):
        u1, u2 = rng.random(len(todo)), rng.random(len(todo))
        su = np.sqrt(u1)
        dv = t[0] * (1 - su)[:, None] + t[1] * (su * (1 - u2))[:, None] + t[2] * (su * u2)[:, None] - p[todo]
        d2 = (dv * dv).sum(1)
        h = np.abs(t[0, 1] - p[todo, 1])
        dx = np.maximum(0, np.maximum(lo[0] - p[todo, 0], p[todo, 0] - hi[0]))
        dz = np.maximum(0, np.maximum(lo[2] - p[todo, 2], p[todo, 2] - hi[2]))
        ok = rng.random(len(todo)) < (h / d2 ** 1.5) / (h / (h * h + dx * dx + dz * dz) ** 1.5)
        out[todo[ok]] = dv[ok] / np.sqrt(d2[ok])[:, None]
        todo = todo[~ok]
    return out


def estimate(rng, p):
    """One sample of the estimator (luminance) at each point p of the back wall (normal -z)."""
    n = len(p)
    omega = np.stack([solid_angle(p, t) for t in TRIANGLES], 1)
    first = rng.random(n) < 0.5
    wi = np.empty((n, 3))
    for k, sel in enumerate((first, ~first)):
        wi[sel] = uniform_solid_angle(rng, p[sel], TRIANGLES[k])
    pdf_light = 0.5 / np.where(first, omega[:, 0], omega[:, 1])
    cos = np.clip(-wi[:, 2], 0, None)
    pdf_bsdf = cos / np.pi
    nee = cos / np.pi / pdf_light * pdf_light ** 2 / (pdf_light ** 2 + pdf_bsdf ** 2)
    u1, u2 = rng.random(n), rng.random(n)
    r, phi = np.sqrt(u1), 2 * np.pi * u2
    d = np.stack([r * np.cos(phi), r * np.sin(phi), -np.sqrt(1 - u1)], 1)
    pdf_bsdf = np.sqrt(1 - u1) / np.pi
    bsdf = np.zeros(n)
    for k, t in enumerate(TRIANGLES):
        pdf_light = 0.5 / omega[:, k]
        bsdf = np.where(hits(p, d, t), pdf_bsdf ** 2 / (pdf_bsdf ** 2 + pdf_light ** 2), bsdf)
    return SCALE * (nee + bsdf)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("maps", help="a --maps file of bench/direct_light_cycles.py (64x64)")
    ap.add_argument("--samples", type=int, default=400000)
    ap.add_argument("--setting", default="solid_angle")
    a = ap.parse_args()
    m = np.load(a.maps)
    rng = np.random.default_rng(1)
    print("pixel    model centre: mean variance  model jittered: mean variance  "
          f"pt {a.setting}: mean variance  Cycles: mean variance")
    for i, j in PIXELS:
        c = estimate(rng, wall_points(i, j, np.full((a.samples, 2), 0.5)))
        s = estimate(rng, wall_points(i, j, rng.random((a.samples, 2))))
        print(f"{i:2d},{j:2d}    {c.mean():.5f} {c.var():.3e}         {s.mean():.5f} {s.var():.3e}           "
              f"{m[a.setting + '_mean'][i, j]:.5f} {m[a.setting + '_var'][i, j]:.3e}      "
              f"{m['cycles_mean'][i, j]:.5f} {m['cycles_var'][i, j]:.3e}")


if __name__ == "__main__":
    main()
