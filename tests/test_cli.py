"""The `restir` command line: every option takes effect for the chosen method or is refused with
a usage error that says why and what to use instead; `restir --version`; and `restir compare` as a
CI gate (exit 0 pass, 1 warn, 2 fail, 3 could not compare, --diff's per-pixel error image)."""
import json
import re
import shlex
import subprocess
from pathlib import Path

import numpy as np
import pytest

from conftest import BIN, ROOT, build_commit, read_exr, run_cli
from daemon import BIN as DAEMON_BIN

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


@pytest.mark.parametrize("value", ["real_time", "realtime", "Converge", ""])
def test_profile_takes_only_its_two_spellings(tmp_path, scenes, value):
    assert refused(tmp_path, scenes, "--method", "restir_pt", "--frames", "2", "--profile", value) == (
        f"restir: --profile: expected real-time or converge, got '{value}'")


CONVERGE = {m["name"]: {p["name"]: p["converge_default"] for p in m["params"] if "converge_default" in p}
            for m in METHODS}
PROFILE_SCENE = {"restir_sss": "translucent", "restir_bdpt": "caustic-sphere", "restir_sms": "refractive-slab", "sms": "refractive-slab",
                 "sms_ssp": "refractive-slab"}


@pytest.mark.parametrize("method", sorted(CONVERGE))
def test_profile_converge_is_its_params_and_params_win(tmp_path, scenes, method):
    """--profile converge renders what --params of the registry's converge defaults renders, bit
    for bit (nothing for the methods without any), --profile real-time what no profile renders, and
    a key --params names wins over the profile's value."""
    scene = scenes / PROFILE_SCENE.get(method, "cornell-box")

    def render(name, *args):
        res = run_cli("render", scene, "--method", method, "--size", "8x8", "--frames", "3", "--seed", "5", *args,
                      "-o", tmp_path / name)
        assert res.returncode == 0, res.stderr
        return read_exr(tmp_path / name)

    conv = CONVERGE[method]
    assert bool(conv) == next(m for m in METHODS if m["name"] == method)["capabilities"]["reuses_frames"]
    default = render("none.exr")
    assert np.array_equal(render("rt.exr", "--profile", "real-time"), default)
    profile = render("c.exr", "--profile", "converge")
    assert np.array_equal(profile, render("p.exr", *(["--params", json.dumps(conv)] if conv else [])))
    assert np.array_equal(profile, default) == (not conv)
    # The mean of a still sequence is a still image: --average-last alone means the converge
    # profile, with --animation the real-time one.
    averaged = render("a.exr", "--average-last", "2")
    assert np.array_equal(averaged, render("ac.exr", "--average-last", "2", "--profile", "converge"))
    assert np.array_equal(averaged, render("ar.exr", "--average-last", "2", "--profile", "real-time")) == (not conv)
    anim = tmp_path / "still.json"
    anim.write_text(json.dumps({"animation": {"fps": 30, "frames": 3, "camera_keys": [
        {"t": 0, **json.loads((scene / "scene.json").read_text())["camera"]}]}}))
    animated = render("an.exr", "--average-last", "2", "--animation", str(anim))
    assert np.array_equal(animated, render("anr.exr", "--average-last", "2", "--animation", str(anim),
                                           "--profile", "real-time"))
    if "temporal" in conv:
        # Temporal reuse by the user's word, the profile's other values kept.
        mixed = render("m.exr", "--profile", "converge", "--params", '{"temporal": true}')
        assert np.array_equal(mixed, render("mp.exr", "--params", json.dumps({**conv, "temporal": True})))
        assert not np.array_equal(mixed, profile)


def test_other_silent_cases_are_refused(tmp_path, scenes):
    assert refused(tmp_path, scenes, "--spp", "2", "--spp", "3") == "restir: --spp is given twice: give it once"
    assert refused(tmp_path, scenes, "--frames", "2", "--profile", "converge", "--profile", "converge") == (
        "restir: --profile is given twice: give it once")
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
    # Both programs, one version and one commit: the build's (conftest.build_commit).
    cli = run_cli("--version")
    daemon = subprocess.run([DAEMON_BIN, "--version"], capture_output=True, text=True, timeout=30)
    assert cli.returncode == 0 and daemon.returncode == 0, (cli.stderr, daemon.stderr)
    m = re.fullmatch(r"restir (\d+\.\d+\.\d+) \(commit ([0-9a-f]{7,40}|unknown)\)\n", cli.stdout)
    assert m and m[2] == build_commit(BIN), (cli.stdout, build_commit(BIN))
    assert daemon.stdout == f"restird {m[1]} (commit {m[2]})\n"
    # The commit is linked into the two programs alone: the server library, which every unit
    # test links, holds none, so a new commit relinks no test.
    members = subprocess.run(["gcc-ar", "t", Path(BIN).resolve().parent / "obj" / "libserver.a"],
                             capture_output=True, text=True, timeout=30)
    assert members.returncode == 0 and "prom.o" in members.stdout.split(), members
    assert "version.o" not in members.stdout.split(), members.stdout


# ---- restir compare ------------------------------------------------------------------------------

# A 4x1 reference of fives (mean 5, so MAPE's denominator is R + 0.01 * 5 = 5.05; R + 0.01 would
# be 5.01) and an image whose pixels' relative errors are 0, 0.1, 0.5 and 1: MAPE 0.4.
REF = np.full((1, 4, 3), 5.0, dtype=np.float32)
REL = [0.0, 0.1, 0.5, 1.0]
IMG = (5.0 + 5.05 * np.array(REL, dtype=np.float32))[None, :, None].repeat(3, axis=2)


@pytest.fixture
def pair(tmp_path):
    from test_daemon import write_exr
    write_exr(tmp_path / "img.exr", IMG)
    write_exr(tmp_path / "ref.exr", REF)
    return tmp_path / "img.exr", tmp_path / "ref.exr"


def compare(*args):
    res = run_cli("compare", *args)
    return res, (json.loads(res.stdout) if res.stdout else None)


def test_compare_passes_an_image_against_itself(pair):
    res, out = compare(pair[1], pair[1], "--fail-mape", "0", "--fail-rmse", "0", "--fail-relmse", "0",
                       "--fail-percent", "0", "--pixel-threshold", "0")
    assert res.returncode == 0, res.stderr
    assert out["verdict"] == "pass" and out["tripped"] == [] and out["percent_above"] == 0
    assert res.stderr == "restir compare: pass (mape 0, relmse 0, rmse 0)\n"


def test_compare_warns_between_the_levels(pair):
    res, out = compare(*pair, "--warn-mape", "0.3", "--fail-mape", "0.5", "--json")
    assert res.returncode == 1, res.stderr
    assert out["mape"] == pytest.approx(0.4, abs=1e-6)
    assert out["verdict"] == "warn"
    assert [(t["metric"], t["level"], t["threshold"]) for t in out["tripped"]] == [("mape", "warn", 0.3)]
    assert res.stderr == "restir compare: warn (mape 0.4 > warn level 0.3)\n"
    # Above both levels it fails; under both it passes.
    assert compare(*pair, "--warn-mape", "0.1", "--fail-mape", "0.35")[0].returncode == 2
    assert compare(*pair, "--warn-mape", "0.41", "--fail-mape", "0.5")[0].returncode == 0


def test_compare_fails_on_any_metric_or_the_pixel_rule(pair):
    rmse = float(np.sqrt(np.mean((IMG.astype(np.float64) - 5.0) ** 2)))
    res, out = compare(*pair, "--fail-rmse", "0.5", "--warn-relmse", "0.01")
    assert res.returncode == 2, res.stderr
    assert out["rmse"] == pytest.approx(rmse, rel=1e-6)
    assert out["verdict"] == "fail"
    assert [(t["metric"], t["level"]) for t in out["tripped"]] == [("relmse", "warn"), ("rmse", "fail")]
    # One pixel in four (25 %) has a relative error above 0.6: more than 20 % fails, 25 % does not.
    res, out = compare(*pair, "--fail-percent", "20", "--pixel-threshold", "0.6")
    assert res.returncode == 2 and out["percent_above"] == 25, res.stderr
    assert out["tripped"] == [{"metric": "percent_above", "level": "fail", "value": 25, "threshold": 20,
                               "pixel_threshold": 0.6}]
    assert res.stderr == ("restir compare: fail (25 % of the pixels have a relative error above 0.6 > fail "
                          "level 20 %)\n")
    assert compare(*pair, "--fail-percent", "25", "--pixel-threshold", "0.6")[0].returncode == 0
    assert compare(*pair, "--fail-percent", "25", "--pixel-threshold", "0.45")[1]["percent_above"] == 50


def test_compare_gates_the_difference_of_the_means(pair):
    # IMG's mean is 5 + 5.05 * 0.4 = 7.02 in every channel against REF's 5: off by 0.404.
    res, out = compare(*pair, "--warn-mean", "0.3", "--fail-mean", "0.5")
    assert res.returncode == 1, res.stderr
    assert out["mean"]["b"] == [5, 5, 5] and out["mean"]["a"] == pytest.approx([7.02] * 3, rel=1e-6)
    assert out["mean_rel_diff"] == pytest.approx([0.404] * 3, rel=1e-5)
    assert out["mean_rel_diff_max"] == pytest.approx(0.404, rel=1e-5)
    assert [(t["metric"], t["level"], t["threshold"]) for t in out["tripped"]] == [("mean", "warn", 0.3)]
    assert res.stderr == "restir compare: warn (|mean A / mean B - 1| (largest channel) 0.404 > warn level 0.3)\n"
    assert compare(*pair, "--fail-mean", "0.4")[0].returncode == 2
    assert compare(*pair, "--fail-mean", "0.41")[0].returncode == 0


def test_compare_fails_a_metric_that_is_not_a_number(tmp_path, pair):
    # An image of NaN leaves no pixel to compare: no evidence that it is close, so a level set fails.
    from test_daemon import write_exr
    write_exr(tmp_path / "nan.exr", np.full((1, 4, 3), np.nan, dtype=np.float32))
    res, out = compare(tmp_path / "nan.exr", pair[1], "--fail-mape", "1")
    assert res.returncode == 2, res.stderr
    assert out["mape"] is None and out["nan"]["a"] == 4 and out["verdict"] == "fail"


def test_compare_fails_an_image_with_a_nan_pixel_by_default(tmp_path, pair):
    # One NaN pixel against a clean reference, and no level given: the three pixels left are
    # identical, so only the NaN can fail it. Its error is infinite: above any pixel threshold,
    # and +Inf in --diff. --fail-nonfinite 1 allows it.
    from test_daemon import write_exr
    img = REF.copy()
    img[0, 1, 0] = np.nan
    write_exr(tmp_path / "one-nan.exr", img)
    res, out = compare(tmp_path / "one-nan.exr", pair[1], "--diff", tmp_path / "d.exr")
    assert res.returncode == 2, res.stderr
    assert out["mape"] == 0 and out["nonfinite"] == {"a": 1, "b": 0}
    assert out["tripped"] == [{"metric": "nonfinite", "level": "fail", "value": 1, "threshold": 0}]
    assert res.stderr == f"restir compare: fail (NaN or Inf pixels in {tmp_path}/one-nan.exr: 1 > fail level 0)\n"
    assert read_exr(tmp_path / "d.exr")[0, :, 0].tolist() == [0, np.inf, 0, 0]
    res, out = compare(tmp_path / "one-nan.exr", pair[1], "--fail-nonfinite", "1", "--fail-percent", "20",
                       "--pixel-threshold", "1e30")
    assert res.returncode == 2 and out["percent_above"] == 25, res.stderr
    assert [t["metric"] for t in out["tripped"]] == ["percent_above"]
    assert compare(tmp_path / "one-nan.exr", pair[1], "--fail-nonfinite", "1")[0].returncode == 0


def test_compare_could_not_compare(tmp_path, pair):
    from test_daemon import write_exr
    write_exr(tmp_path / "small.exr", np.ones((1, 2, 3), dtype=np.float32))
    (tmp_path / "text.exr").write_text("not an image")
    cases = [((pair[0], tmp_path / "small.exr"), "restir: image is 4x1 but reference is 2x1"),
             ((pair[0], tmp_path / "missing.exr"), f"restir: {tmp_path}/missing.exr: cannot open: No such file or directory"),
             ((pair[0], tmp_path / "text.exr"), f"restir: {tmp_path}/text.exr: not an OpenEXR file (bad magic number or too short)"),
             ((pair[0],), "restir: compare needs exactly two EXR files"),
             ((*pair, "--fail-mape", "x"), "restir: --fail-mape: expected a number >= 0, got 'x'"),
             ((*pair, "--fail-mape", "0.1", "--fail-mape", "0.2"), "restir: --fail-mape is given twice: give it once"),
             ((*pair, "--warn-rmse", "0.2", "--fail-rmse", "0.1"),
              "restir: --warn-rmse 0.2 is above --fail-rmse 0.1: a warning level sits below the failing one"),
             ((*pair, "--fail-percent", "5"), "restir: --fail-percent P and --pixel-threshold T go together: fail "
              "when more than P % of the pixels have a relative error above T"),
             ((*pair, "--fail-percent", "101", "--pixel-threshold", "1"),
              "restir: --fail-percent: expected a percentage, 0..100"),
             ((*pair, "--fail-nonfinite", "1.5"), "restir: --fail-nonfinite: expected a whole number of pixels >= 0"),
             ((*pair, "--diff", tmp_path / "d.jpg"),
              f"restir: --diff: '{tmp_path}/d.jpg' names no format: end it in .exr, or .png for an 8-bit view"),
             ((*pair, "--diff", tmp_path / "no" / "d.exr"), f"restir: cannot write {tmp_path}/no/d.exr: its folder does not exist"),
             ((*pair, "--frobnicate", "1"), "restir: unknown option '--frobnicate'")]
    for args, message in cases:
        res, _ = compare(*args)
        assert res.returncode == 3, (args, res.stderr)
        assert first_line(res) == message, (args, res.stderr)
        assert "verdict" not in res.stdout
    assert not (tmp_path / "d.jpg").exists()


def test_compare_diff_writes_the_relative_error_per_pixel(tmp_path, pair):
    res, _ = compare(*pair, "--diff", tmp_path / "d.exr")
    assert res.returncode == 0, res.stderr
    d = read_exr(tmp_path / "d.exr")
    assert d.shape == (1, 4, 3)
    np.testing.assert_allclose(d[0, :, 0], REL, atol=1e-6)
    assert np.array_equal(d[..., 0], d[..., 1]) and np.array_equal(d[..., 0], d[..., 2])
    # Their mean is the MAPE the JSON reports.
    assert float(d[..., 0].mean()) == pytest.approx(json.loads(res.stdout)["mape"], rel=1e-6)
    # .png: 8 bits through the preview's tone mapper: black at 0, white at 1 and above.
    res, _ = compare(*pair, "--diff", tmp_path / "d.png")
    assert res.returncode == 0, res.stderr
    png = read_exr(tmp_path / "d.png")
    assert png.shape[:2] == (1, 4)
    assert png[0, 0, :3].tolist() == [0, 0, 0] and png[0, 3, :3].tolist() == [1, 1, 1]
    assert 0 < png[0, 1, 0] < png[0, 2, 0] < 1


def readme_recipe():
    """README.md's CI recipe: the golden image's render options (between `render` and `-o`) and
    the job's compare options (without --diff), as the README shows them."""
    block = (ROOT / "README.md").read_text().split("## CI recipe")[1].split("```sh\n")[1].split("```")[0]
    lines = block.replace("\\\n", " ").splitlines()
    render = shlex.split(next(line for line in lines if line.endswith("-o out/golden.exr")))
    gate = shlex.split(next(line for line in lines if line.startswith("build/restir compare out/candidate.exr")))
    gate = gate[4:gate.index("||")]
    i = gate.index("--diff")
    return render[2:render.index("-o")], gate[:i] + gate[i + 2:]


def test_the_readme_ci_gate_fails_a_biased_image_and_passes_another_seed(tmp_path):
    # A bias of the whole image by 10 or 20 % hides in the per-pixel noise: the gate's per-pixel
    # levels alone pass it, its mean levels fail it. Another seed is noise only: it passes.
    render, gate = readme_recipe()
    assert "--fail-mean" in gate, gate
    paths = {}
    for seed in ("1", "2"):
        args = list(render)
        args[args.index("--seed") + 1] = seed
        paths[seed] = tmp_path / f"seed-{seed}.exr"
        res = run_cli("render", *[ROOT / a if a.startswith("scenes/") else a for a in args], "-o", paths[seed])
        assert res.returncode == 0, res.stderr
    golden = paths["1"]
    res, out = compare(paths["2"], golden, *gate)
    assert res.returncode == 0, res.stderr
    from test_daemon import write_exr
    per_pixel = [a for i, a in enumerate(gate) if "-mean" not in a and "-mean" not in gate[i - 1]]
    for scale in (1.1, 1.2):
        write_exr(tmp_path / "biased.exr", (read_exr(golden)[..., :3] * scale).astype(np.float32))
        res, out = compare(tmp_path / "biased.exr", golden, *gate)
        assert res.returncode == 2, (scale, res.stderr)
        assert out["mean_rel_diff_max"] == pytest.approx(scale - 1, rel=1e-5)
        assert [t["metric"] for t in out["tripped"]] == ["mean"], out["tripped"]
        assert compare(tmp_path / "biased.exr", golden, *per_pixel)[0].returncode == 0, scale
