"""Subsurface scattering in the reference path tracer (`pt`): the translucent material's BSSRDF
importance sampling at the primary hit (renderer/material/bssrdf.c, reference_pt.c pt_sss_primary).

- an analytic furnace: a large translucent plane under a uniform environment returns exactly
  albedo (1 - F(wo)) (the profile integrates to 1 over the plane, the entry lobe's cosine
  integral to 1), with NEE and without it; a x1.03 image must fail;
- two independent estimators agree: NEE at every probe hit against emission reached by the
  cosine-sampled continuation (--no-nee), in a scene with an area light, an environment and an
  occluder; a x1.03 image must fail;
- the library scene `translucent` renders finite, its lit region is much brighter than its
  shadowed one, and diffusion carries light across the shadow boundary (brighter there than a
  diffuse sphere of the same albedo)."""
import json
import math

import numpy as np
import pytest

from conftest import render
from stats import assert_agree, ztest_runs


def _runs(scene, tmp_path, seeds, spp, size, extra=()):
    return np.stack([render(scene, tmp_path / f"r{s}.exr", spp=spp, size=size, seed=s, extra=extra)[0] for s in seeds])


def _fresnel(cos_i, eta):
    sin2_t = (1 - cos_i * cos_i) / (eta * eta)
    cos_t = math.sqrt(1 - sin2_t)
    rs = (cos_i - eta * cos_t) / (cos_i + eta * cos_t)
    rp = (eta * cos_i - cos_t) / (eta * cos_i + cos_t)
    return 0.5 * (rs * rs + rp * rp)


ALBEDO = [0.9, 0.6, 0.3]
IOR = 1.4


def _furnace_scene(tmp_path):
    # Looking straight down with a 6 degree field of view: every camera ray meets the plane
    # within 4.3 degrees of the normal, where 1 - F changes by < 2e-5 (relative), far below the
    # test's resolution. The plane is 60 x 60 around the view, r_max of the widest channel ~0.9.
    scene = {
        "camera": {"position": [0, 10, 0], "look_at": [0, 0, 0], "up": [0, 0, -1], "fov_deg": 6},
        "materials": {"wax": {"type": "translucent", "albedo": ALBEDO, "mfp": [0.05, 0.03, 0.02], "ior": IOR}},
        "shapes": [{"type": "quad", "material": "wax",
                    "vertices": [[-30, 0, -30], [-30, 0, 30], [30, 0, 30], [30, 0, -30]]}],
        "environment": {"radiance": [1, 1, 1]},
    }
    path = tmp_path / "furnace.json"
    path.write_text(json.dumps(scene))
    return path


@pytest.mark.statistical
@pytest.mark.parametrize("extra", [(), ("--no-nee",)], ids=["nee", "no-nee"])
def test_translucent_furnace_plane(tmp_path, extra):
    path = _furnace_scene(tmp_path)
    # 1024 spp per run: a pixel's expectation is carried by rare large samples (the normal-axis,
    # red-channel technique with a light sample above the horizon, ~1 in 12, worth ~10x the
    # mean), so runs need many samples before their means are close enough to normal for a z-test.
    runs = _runs(path, tmp_path, range(16), spp=1024, size="12x12", extra=extra)
    assert np.isfinite(runs).all()
    expected = np.array(ALBEDO) * (1 - _fresnel(1.0, IOR))
    res = ztest_runs(runs, expected=np.broadcast_to(expected, runs.shape[1:]))
    assert_agree(res)
    assert not ztest_runs(runs * 1.03, expected=np.broadcast_to(expected, runs.shape[1:])).passed


@pytest.mark.statistical
def test_translucent_nee_agrees_with_continuation(tmp_path):
    """NEE through the entry lobe at every probe hit, against the same direct light found only by
    the cosine-sampled continuation from one picked hit (weighted by the hit count). Checked to
    fail when the continuation forgets the hit-count factor N, and when the MIS pdf leaves out
    the tangent axes."""
    scene = {
        "camera": {"position": [1.2, 1.3, 2.6], "look_at": [0, 0.45, 0], "up": [0, 1, 0], "fov_deg": 24},
        "materials": {
            "wax": {"type": "translucent", "albedo": [0.9, 0.7, 0.5], "mfp": [0.08, 0.04, 0.02], "ior": 1.4},
            "floor": {"type": "diffuse", "albedo": [0.5, 0.5, 0.5]},
            "lamp": {"type": "diffuse", "albedo": [0, 0, 0], "emission": [2, 2, 2]},
        },
        "shapes": [
            {"type": "quad", "material": "floor", "vertices": [[-4, 0, -4], [-4, 0, 4], [4, 0, 4], [4, 0, -4]]},
            {"type": "sphere", "material": "wax", "center": [0, 0.5, 0], "radius": 0.5},
            {"type": "quad", "material": "floor", "vertices": [[0.8, 0, -0.8], [0.8, 0.5, -0.8], [0.8, 0.5, 0.8], [0.8, 0, 0.8]]},
            {"type": "quad", "material": "lamp", "vertices": [[2.5, 0.2, 1], [2.5, 1.8, 1], [2.5, 1.8, -1], [2.5, 0.2, -1]]},
        ],
        "environment": {"radiance": [0.15, 0.15, 0.2]},
    }
    path = tmp_path / "sss.json"
    path.write_text(json.dumps(scene))
    nee = _runs(path, tmp_path, range(16), spp=32, size="20x20")
    cont = _runs(path, tmp_path, range(500, 516), spp=96, size="20x20", extra=["--no-nee"])
    res = ztest_runs(nee, cont)
    assert_agree(res)
    assert not ztest_runs(nee * 1.03, cont).passed


def test_translucent_scene_lit_and_shadowed(tmp_path, scenes):
    path = scenes / "translucent" / "scene.json"
    img, st = render(path, tmp_path / "t.exr", spp=64, size="32x32")
    assert np.isfinite(img).all() and (img >= 0).all() and st["nonfinite"] == 0
    lum = img.mean(axis=2)
    # At 32 x 32 the sphere covers rows 5-22, columns 9-25; the occluder's shadow edge crosses it
    # at rows 15-16 (the light grazes from +x at the sphere's mid height).
    lit, shadow = lum[8:13, 18:23].mean(), lum[18:21, 13:21].mean()
    assert lit > 5 * shadow > 0, (lit, shadow)
    # The same sphere as a diffuse surface of the same albedo: below the shadow edge, light that
    # entered the lit part and diffused under the surface makes the translucent one brighter.
    scene = json.loads(path.read_text())
    scene["materials"]["wax"] = {"type": "diffuse", "albedo": scene["materials"]["wax"]["albedo"]}
    dpath = tmp_path / "diffuse.json"
    dpath.write_text(json.dumps(scene))
    dimg, _ = render(dpath, tmp_path / "d.exr", spp=64, size="32x32")
    band, dband = lum[16:18, 14:22].mean(), dimg.mean(axis=2)[16:18, 14:22].mean()
    assert band > 1.5 * dband, (band, dband)
