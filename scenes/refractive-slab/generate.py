#!/usr/bin/env python3
"""Writes the bumpy meshes of refractive-slab (slab.obj) and reflective-plane (plane.obj).

Heights are sums of a few sines, so normals are exact analytic gradients (the manifold walk
differentiates the interpolated vertex normals). Run from anywhere:
  /usr/bin/python3 scenes/refractive-slab/generate.py
writes the library's meshes; with --out DIR (and --slab-freq / --plane-freq) it writes copies of
both scenes with other bumps into DIR/refractive-slab and DIR/reflective-plane (bench/sms.py's
sweep of the normal variation).
"""
import argparse
import math
import os
import shutil

HERE = os.path.dirname(os.path.abspath(__file__))


# The sines of `bumps`: wave numbers along x and z at a scale of 1, and phase.
TERMS = [(2.7, 1.9, 0.0), (-1.6, 3.1, 1.3), (4.3, -0.7, 2.1)]


def bumps(x, z, amp, freq, phase):
    """Height and its gradient (dh/dx, dh/dz); freq scales the wave numbers."""
    h = hx = hz = 0.0
    for kx, kz, ph in TERMS:
        kx, kz = freq * kx, freq * kz
        a = kx * x + kz * z + ph + phase
        h += amp * math.sin(a)
        hx += amp * kx * math.cos(a)
        hz += amp * kz * math.cos(a)
    return h, hx, hz


def grid(n, half, y0, amp, freq, phase, up, out_v, out_n, out_f):
    """One bumpy (n+1)^2 grid over [-half, half]^2 at height y0; faces front towards +y when up."""
    base = len(out_v)
    for j in range(n + 1):
        for i in range(n + 1):
            x = -half + 2 * half * i / n
            z = -half + 2 * half * j / n
            h, hx, hz = bumps(x, z, amp, freq, phase)
            nx, ny, nz = -hx, 1.0, -hz
            l = math.sqrt(nx * nx + ny * ny + nz * nz)
            s = 1.0 if up else -1.0
            out_v.append((x, y0 + h, z))
            out_n.append((s * nx / l, s * ny / l, s * nz / l))
    for j in range(n):
        for i in range(n):
            a = base + j * (n + 1) + i
            b, c, d = a + 1, a + n + 2, a + n + 1
            # (a, d, c) winds counter-clockwise seen from +y.
            if up:
                out_f += [(a, d, c), (a, c, b)]
            else:
                out_f += [(a, c, d), (a, b, c)]
    return base


def write_obj(path, verts, norms, faces, header):
    with open(path, "w") as f:
        f.write(header)
        for v in verts:
            f.write("v %.6f %.6f %.6f\n" % v)
        for n in norms:
            f.write("vn %.6f %.6f %.6f\n" % n)
        for a, b, c in faces:
            f.write("f %d//%d %d//%d %d//%d\n" % (a + 1, a + 1, b + 1, b + 1, c + 1, c + 1))


# How bumpy the two casters are: a scale of the wave numbers of `bumps`. At 1 (the library's) the
# casters undulate gently: one SMS seed in three (slab) or two (plane) finds a solution. [SMS-SSP]
# measures its method where SMS struggles (its Table 1: 9.4 % and 8.1 %); bench/sms.py renders
# copies at larger scales to show that regime (docs/benchmarks.md, "Near-square tiles, and how
# bumpy the casters are").
SLAB_FREQ = 1.0
PLANE_FREQ = 1.0
MAX_K = max(math.hypot(kx, kz) for kx, kz, _ in TERMS)  # the largest wave number at a scale of 1


def grid_size(half, freq, minimum):
    """Grid cells across [-half, half]: at least 12 per shortest wavelength."""
    wavelength = 2.0 * math.pi / (freq * MAX_K)
    return max(minimum, math.ceil(12.0 * 2.0 * half / wavelength))


def slab(freq, out_dir):
    """Closed slab: bumpy top (front +y) and bottom (front -y) grids and four flat side walls."""
    half = 0.6
    n = grid_size(half, freq, 16)
    v, nn, f = [], [], []
    top = grid(n, half, 0.9, 0.02, freq, 0.0, True, v, nn, f)
    bot = grid(n, half, 0.75, 0.02, freq, 1.7, False, v, nn, f)

    def idx(base, i, j):
        return base + j * (n + 1) + i

    # Side walls: each quad joins a top edge vertex pair with the bottom pair below it; the side
    # vertices are duplicated with the flat outward normal so the walls are flat-shaded.
    edges = [
        ([(i, 0) for i in range(n + 1)], (0.0, 0.0, -1.0)),
        ([(n, j) for j in range(n + 1)], (1.0, 0.0, 0.0)),
        ([(i, n) for i in range(n, -1, -1)], (0.0, 0.0, 1.0)),
        ([(0, j) for j in range(n, -1, -1)], (-1.0, 0.0, 0.0)),
    ]
    for path, normal in edges:
        for k in range(len(path) - 1):
            (i0, j0), (i1, j1) = path[k], path[k + 1]
            quad = [v[idx(top, i0, j0)], v[idx(top, i1, j1)], v[idx(bot, i1, j1)], v[idx(bot, i0, j0)]]
            b = len(v)
            for p in quad:
                v.append(p)
                nn.append(normal)
            # Wind so the front faces outwards (along `normal`).
            e1 = [quad[1][t] - quad[0][t] for t in range(3)]
            e2 = [quad[2][t] - quad[0][t] for t in range(3)]
            cr = (e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2], e1[0] * e2[1] - e1[1] * e2[0])
            if sum(cr[t] * normal[t] for t in range(3)) > 0:
                f += [(b, b + 1, b + 2), (b, b + 2, b + 3)]
            else:
                f += [(b, b + 2, b + 1), (b, b + 3, b + 2)]
    write_obj(os.path.join(out_dir, "slab.obj"), v, nn, f,
              "# refractive-slab: bumpy two-sided glass slab (scenes/refractive-slab/generate.py)\n")


def plane(freq, out_dir):
    half = 0.8
    n = grid_size(half, freq, 24)
    v, nn, f = [], [], []
    grid(n, half, 0.0, 0.008, freq, 0.4, True, v, nn, f)
    write_obj(os.path.join(out_dir, "plane.obj"), v, nn, f,
              "# reflective-plane: bumpy metal plane (scenes/refractive-slab/generate.py)\n")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", help="write copies of both scenes under this directory")
    ap.add_argument("--slab-freq", type=float, default=SLAB_FREQ)
    ap.add_argument("--plane-freq", type=float, default=PLANE_FREQ)
    a = ap.parse_args()
    scenes = os.path.dirname(HERE)
    slab_dir, plane_dir = HERE, os.path.join(scenes, "reflective-plane")
    if a.out:
        slab_dir, plane_dir = os.path.join(a.out, "refractive-slab"), os.path.join(a.out, "reflective-plane")
        for src, dst in ((HERE, slab_dir), (os.path.join(scenes, "reflective-plane"), plane_dir)):
            os.makedirs(dst, exist_ok=True)
            shutil.copy(os.path.join(src, "scene.json"), dst)
    slab(a.slab_freq, slab_dir)
    plane(a.plane_freq, plane_dir)


if __name__ == "__main__":
    main()
