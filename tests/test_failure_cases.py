"""The papers' known failure cases, reproduced at small sizes: each test shows the weak regime is
present (so a scene change that removes it is noticed) and that the method stays correct inside
it. bench/report.py charts the same cases at the report's size. (restir_pt with next-event estimation blocked by glass is in test_stability.py.)

* Light tracing wasted on lights the camera cannot see ([ReSTIR BDPT Fig. 10]): in door-ajar the
  only light is outside the room, so almost no light subpath of `bdpt` reaches a point the
  camera sees.
* Shadow boundaries for the hybrid shift of ReSTIR SSS ([ReSTIR SSS Fig. 5]): the criterion
  decides per path from local distances and normals, so along the occluder's shadow on the wax
  sphere it cannot always choose the better shift; the sequential shift applies both."""
import json

import numpy as np
import pytest

from conftest import ROOT, render

SIZE = 32


def _light_tracing(scene, tmp_path):
    _, st = render(ROOT / "scenes" / scene / "scene.json", tmp_path / f"{scene}.exr", spp=1, size=f"{SIZE}x{SIZE}",
                   seed=3, extra=["--method", "bdpt", "--frames", "4"])
    f = st["last_frame"]
    return f["light_traced"] / f["light_subpaths"], f


def test_light_tracing_wasted_on_hidden_light(tmp_path):
    """bdpt's light-traced samples per light subpath: on cornell-box (light and camera in one
    room) every subpath lands about one on the image; on door-ajar under 5 % do, while the light
    pass still traces all of them (its time is in the frame stats: `light_ms`)."""
    hidden, fh = _light_tracing("door-ajar", tmp_path)
    seen, fs = _light_tracing("cornell-box", tmp_path)
    print(f"light-traced samples per light subpath: door-ajar {hidden:.3f} (light pass {fh['light_ms']:.1f} ms of "
          f"{fh['light_ms'] + fh['camera_ms']:.1f}), cornell-box {seen:.3f}")
    assert fh["light_subpaths"] == fs["light_subpaths"] == SIZE * SIZE
    assert seen > 0.5
    assert hidden < 0.05


# ---- ReSTIR SSS at shadow boundaries --------------------------------------------------------------

def _variant(tmp_path, name, wax, others_black=True, lamp_on=True):
    """scenes/translucent with the wax replaced by `wax` and, optionally, every other surface
    black (so only the sphere shows) and the lamp off."""
    sc = json.loads((ROOT / "scenes" / "translucent" / "scene.json").read_text())
    sc["materials"]["wax"] = wax
    if others_black:
        sc["materials"]["floor"]["albedo"] = [0, 0, 0]
        sc["materials"]["wall"]["albedo"] = [0, 0, 0]
    if not lamp_on:
        sc["materials"]["lamp"]["emission"] = [0, 0, 0]
    path = tmp_path / f"{name}.json"
    path.write_text(json.dumps(sc))
    return path


def boundary_masks(tmp_path, size=SIZE):
    """(sphere, band, lit, dark): pixels fully covered by the sphere (it made emissive, everything
    else black); those of them the lamp lights directly (above a quarter of the 90th percentile)
    or not at all (below 2 % of it), with the sphere made white diffuse, direct light only, the
    other surfaces black; and the band: sphere pixels within one pixel of both a lit and a dark
    one."""
    glow = _variant(tmp_path, "glow", {"type": "diffuse", "albedo": [0, 0, 0], "emission": [1, 1, 1]}, lamp_on=False)
    cover, _ = render(glow, tmp_path / "glow.exr", spp=16, size=f"{size}x{size}", seed=1)
    sphere = cover.mean(axis=2) > 0.999
    white = _variant(tmp_path, "white", {"type": "diffuse", "albedo": [1, 1, 1]})
    direct, _ = render(white, tmp_path / "white.exr", spp=64, size=f"{size}x{size}", seed=1,
                       extra=["--max-depth", "1"])
    lum = direct.mean(axis=2)
    top = np.percentile(lum[sphere], 90)
    lit, dark = sphere & (lum > 0.25 * top), sphere & (lum < 0.02 * top)
    pad = lambda m: np.pad(m, 1)  # noqa: E731
    near = lambda m: np.any([pad(m)[1 + dy:1 + dy + size, 1 + dx:1 + dx + size]  # noqa: E731
                             for dy in (-1, 0, 1) for dx in (-1, 0, 1)], axis=0)
    return sphere, sphere & near(lit) & near(dark), lit, dark


@pytest.mark.statistical
def test_restir_sss_shadow_boundary(tmp_path, scenes):
    """On the shadow boundary band of the wax sphere, restir_sss with the hybrid and the
    sequential shift: the band's mean over frames 5-24 (64 sessions) agrees with the pt reference
    within 4 standard errors of the sessions' spread, which must be small enough to see a bias of
    15 % (light carried under the occluder's shadow arrives in rare long subsurface paths: one
    session's band mean varies by about 20 %). What the weak criterion costs is noise, not bias:
    bench/report.py charts the band's error per shift."""
    sphere, band, _, _ = boundary_masks(tmp_path)
    assert band.sum() >= 8, f"no shadow boundary on the sphere ({band.sum()} pixels)"
    scene = scenes / "translucent" / "scene.json"
    ref, _ = render(scene, tmp_path / "ref.exr", spp=2048, size=f"{SIZE}x{SIZE}", seed=11)
    ref_band = float(ref[band].mean())

    def run(shift, seed, frames, average=1):
        img, _ = render(scene, tmp_path / f"{shift}{seed}_{frames}.exr", spp=1, size=f"{SIZE}x{SIZE}", seed=seed,
                        extra=["--method", "restir_sss", "--frames", str(frames), "--average-last", str(average),
                               "--profile", "real-time", "--params", json.dumps({"shift": shift})])
        return img

    for shift in ("hybrid", "sequential"):
        means = [float(run(shift, seed, 24, 20)[band].mean()) for seed in range(64)]
        m, se = float(np.mean(means)), float(np.std(means, ddof=1) / np.sqrt(len(means)))
        print(f"{shift}: band ({band.sum()} px) mean {m:.4f} ± {se:.4f}, reference {ref_band:.4f}")
        assert 4 * se <= 0.15 * ref_band, (shift, se, ref_band)
        assert abs(m - ref_band) <= 4 * se, (shift, m, se, ref_band)
        assert abs(1.2 * m - ref_band) > 4 * se, "the same renders scaled by 1.2 must be rejected"
