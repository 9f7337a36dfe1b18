"""The `restir` command line: every option takes effect for the chosen method or is refused with
a usage error that says why and what to use instead; `restir --version`; and `restir compare` as a
CI gate (exit 0 pass, 1 warn, 2 fail, 3 could not compare, --diff's per-pixel error image)."""
import json
import re

import numpy as np
import pytest

from conftest import read_exr, run_cli

METHODS = json.loads(run_cli("methods", "--json").stdout)["methods"]
PARAMS = {m["name"]: {p["name"] for p in m["params"]} for m in METHODS}
NO_SPP = [m["name"] for m in METHODS if not m["capabilities"]["takes_spp"]]
NEE_SWITCH = [name for name, keys in PARAMS.items() if keys & {"nee", "nee_candidates"}]
NO_NEE_SWITCH = [name for name in PARAMS if name not in NEE_SWITCH]


def first_line(res):
    return res.stderr.splitlines()[0] if res.stderr else ""


def refused(tmp_path, scenes, *args, scene="cornell-box"):
    res = run_cli("render", scenes / scene, "--size", "8x8", *args, "-o", tmp_path / "x.exr")
    assert res.returncode == 2, (args, res.stderr)
    assert not (tmp_path / "x.exr").exists()
    return first_line(res)


def test_the_registry_splits_the_methods_as_the_refusals_expect():
    # The lists the refusals below run over, read from the registry: if a method gains spp or a
    # NEE switch, these tests follow it.
    assert sorted(NO_SPP) == ["bdpt", "restir_bdpt", "restir_pt", "restir_sms", "restir_sss"]
    assert sorted(NO_NEE_SWITCH) == ["bdpt", "restir_bdpt", "restir_sms", "restir_sss"]


@pytest.mark.parametrize("method", NO_SPP)
def test_spp_is_refused_by_a_method_that_takes_none(tmp_path, scenes, method):
    assert refused(tmp_path, scenes, "--method", method, "--spp", "4") == (
        f"restir: --spp: {method} takes no spp, it traces one path per pixel and frame: render N frames "
        "with --frames N and write their mean with --average-last N")


@pytest.mark.parametrize("method", NO_NEE_SWITCH)
def test_no_nee_is_refused_by_a_method_without_the_switch(tmp_path, scenes, method):
    assert refused(tmp_path, scenes, "--method", method, "--no-nee") == (
        f"restir: --no-nee: {method} has no next-event estimation switch (the methods with one: "
        "pt, restir_pt, sms, sms_ssp)")


@pytest.mark.parametrize("method", NEE_SWITCH)
def test_no_nee_changes_the_image_of_a_method_with_the_switch(tmp_path, scenes, method):
    # The Cornell box's light is small: BSDF sampling alone finds it far less often, so the
    # images differ wherever NEE would have lit a pixel.
    scene = scenes / ("refractive-slab" if "sms" in method else "cornell-box")
    frames = [] if method == "pt" or "spp" in PARAMS[method] else ["--frames", "1"]
    imgs = []
    for i, extra in enumerate([(), ("--no-nee",)]):
        res = run_cli("render", scene, "--method", method, "--size", "8x8", *frames, *extra, "-o", tmp_path / f"{i}.exr")
        assert res.returncode == 0, res.stderr
        imgs.append(read_exr(tmp_path / f"{i}.exr"))
    assert not np.array_equal(*imgs)


def test_an_option_and_params_setting_one_parameter_are_refused(tmp_path, scenes):
    assert refused(tmp_path, scenes, "--method", "sms", "--spp", "8", "--params", '{"spp": 4}', scene="refractive-slab") == (
        'restir: --spp and "spp" in --params both set sms\'s spp: give it once')
    assert refused(tmp_path, scenes, "--method", "restir_pt", "--no-nee", "--params", '{"nee_candidates": 2}') == (
        'restir: --no-nee and "nee_candidates" in --params both set restir_pt\'s nee_candidates: give it once')
    assert refused(tmp_path, scenes, "--method", "bdpt", "--max-depth", "3", "--params", '{"max_depth": 4}') == (
        'restir: --max-depth and "max_depth" in --params both set bdpt\'s max_depth: give it once')
    assert refused(tmp_path, scenes, "--method", "restir_sss", "--rr-depth", "3", "--params", '{"rr_depth": 4}') == (
        'restir: --rr-depth and "rr_depth" in --params both set restir_sss\'s rr_depth: give it once')


def test_an_option_beside_params_takes_effect(tmp_path, scenes):
    # --params leaves max_depth out, so --max-depth sets it: the same image, bit for bit, as
    # --params naming it, and not the image of the default depth.
    def bdpt(name, *args):
        res = run_cli("render", scenes / "cornell-box", "--method", "bdpt", "--size", "8x8", "--frames", "1", *args,
                      "-o", tmp_path / name)
        assert res.returncode == 0, res.stderr
        return read_exr(tmp_path / name)
    option = bdpt("a.exr", "--max-depth", "1", "--params", '{"heuristic": "balance"}')
    params = bdpt("b.exr", "--params", '{"heuristic": "balance", "max_depth": 1}')
    default = bdpt("c.exr", "--params", '{"heuristic": "balance"}')
    assert np.array_equal(option, params)
    assert not np.array_equal(option, default)


def test_an_option_outside_the_method_range_is_refused(tmp_path, scenes):
    assert refused(tmp_path, scenes, "--method", "bdpt", "--max-depth", "0") == (
        "restir: --max-depth: bdpt's max_depth must be in 1..1024, got 0")


def test_a_params_syntax_error_points_into_the_argument(tmp_path, scenes):
    assert refused(tmp_path, scenes, "--method", "bdpt", "--params", "{bad") == (
        "restir: --params: JSON syntax error at byte 1 (line 1, column 2): unexpected 'b', expected '\"' "
        "starting a key")
    assert refused(tmp_path, scenes, "--method", "bdpt", "--params", '{"heuristic": "power",}') == (
        "restir: --params: JSON syntax error at byte 22 (line 1, column 23): unexpected '}', expected '\"' "
        "starting a key")


def test_other_silent_cases_are_refused(tmp_path, scenes):
    assert refused(tmp_path, scenes, "--spp", "2", "--spp", "3") == "restir: --spp is given twice: give it once"
    assert refused(tmp_path, scenes, "--frames", "2", "--average-last", "3") == (
        "restir: --average-last 3 is more frames than --frames 2 renders")
    anim = tmp_path / "anim.json"
    anim.write_text(json.dumps({"animation": {"fps": 10, "frames": 2, "camera_keys": [
        {"t": 0, "position": [278, 273, -800]}, {"t": 0.1, "position": [300, 273, -800]}]}}))
    assert refused(tmp_path, scenes, "--animation", anim, "--average-last", "3") == (
        f"restir: --average-last 3 is more frames than {anim}'s 2")
    assert refused(tmp_path, scenes, "--method", "bdpt", "--crop", "0,0,4,4") == (
        "restir: --crop and --frame are options of a still image of pt")
    assert refused(tmp_path, scenes, "--frames", "2", "--frame", "3") == (
        "restir: --crop and --frame do not combine with --frames or --animation")
    assert refused(tmp_path, scenes, "--params", '{"spp": 2}') == (
        "restir: --params needs --frames, --animation or a method other than pt")


def test_version_names_the_commit():
    res = run_cli("--version")
    assert res.returncode == 0, res.stderr
    assert re.fullmatch(r"restir \d+\.\d+\.\d+ \(commit ([0-9a-f]{7,40}|unknown)\)\n", res.stdout), res.stdout
