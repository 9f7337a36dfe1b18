"""`restir render` beside --params: the options' defaults and the JSON library's one home."""
import json
import re

from conftest import ROOT, run_cli

# cJSON is read through renderer/input/json_read.c by the two readers of untrusted JSON
# (docs/architecture.md): no other source names it, the CLI's --params included.
CJSON_HOMES = {"renderer/input/json_read.c", "renderer/input/json_read.h", "renderer/input/scene_load.c",
               "protocol/request.c"}


def test_cjson_has_one_home():
    users = {str(p.relative_to(ROOT)) for layer in ("renderer", "protocol", "server")
             for p in (ROOT / layer).rglob("*.[ch]") if re.search(r"\bcJSON|cjson/", p.read_text())}
    assert users == CJSON_HOMES


def test_the_spp_default_holds_beside_params_that_leave_spp_out(tmp_path, scenes):
    # The CLI's default (16) is the spp of every method that takes one, --params or not; --params
    # naming spp sets it.
    def spp(*args):
        res = run_cli("render", scenes / "refractive-slab", "--size", "4x4", "--frames", "1", "--json", *args,
                      "-o", tmp_path / "x.exr")
        assert res.returncode == 0, (args, res.stderr)
        return json.loads(res.stdout)["spp"]
    assert spp("--method", "sms") == 16
    assert spp("--method", "sms", "--params", '{"max_depth": 8}') == 16
    assert spp("--method", "pt", "--params", '{"nee": false}') == 16
    assert spp("--method", "sms_ssp", "--params", '{"spp": 2, "max_depth": 8}') == 2


def test_params_with_a_still_pt_image_is_refused_as_documented(tmp_path, scenes):
    # The still image of pt is the path tracer alone (what --crop and --frame take), not a
    # session's frame: --params needs --frames, and the help and the documents say so.
    def render(*args):
        return run_cli("render", scenes / "cornell-box", "--size", "4x4", "--params", '{"nee": false}', *args,
                       "-o", tmp_path / "x.exr")
    res = render()
    assert res.returncode == 2
    assert res.stderr.splitlines()[0] == "restir: --params needs --frames, --animation or a method other than pt"
    assert render("--frames", "1").returncode == 0
    docs = {"--help": run_cli("--help").stdout, "README.md": (ROOT / "README.md").read_text(),
            "docs/methods.md": (ROOT / "docs" / "methods.md").read_text()}
    for name, text in docs.items():
        assert re.search(r"takes\s+no\s+`?--params`?[^.]*--frames 1", text), name


def test_json_reports_the_cpu_time_of_every_path(tmp_path, scenes):
    # cpu_ms, the CPU time of all the render's threads (parallel_cpu_ms), for the still pt image
    # (reference_pt_render) as for a session's frames (view_render): some, and no more than the
    # threads could spend in the render's wall-clock time_ms (the CPU reading spans a little more).
    for args in (["--spp", "8"], ["--method", "restir_pt", "--frames", "3"], ["--method", "bdpt", "--frames", "2"]):
        res = run_cli("render", scenes / "cornell-box", "--size", "32x32", "--threads", "2", "--json", *args,
                      "-o", tmp_path / "x.exr")
        assert res.returncode == 0, (args, res.stderr)
        st = json.loads(res.stdout)
        assert 0 < st["cpu_ms"] <= st["threads"] * (st["time_ms"] + 5.0 * st["frames"]), (args, st)
        # last_frame_cpu_ms, the last frame's alone (what a benchmark times after a warm-up): the
        # whole of a still image's, a part of a sequence's.
        if st["frames"] == 1:
            assert st["last_frame_cpu_ms"] == st["cpu_ms"], (args, st)
        else:
            assert 0 < st["last_frame_cpu_ms"] < st["cpu_ms"], (args, st)
