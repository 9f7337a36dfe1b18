"""The report's configuration variables (bench/report.py, bench/regimes.py) and bench/sweep.py's
parameters: a bad value is refused naming the variable and the item, a filter measures what it
names and nothing else, and the parameters REPORT_PARAMS gives a method reach every session of it
beneath the row's own."""
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


def report_module(env, code):
    """Imports bench/report.py under `env` and runs `code`; (exit status, stdout, stderr)."""
    full = {k: v for k, v in os.environ.items() if not k.startswith("REPORT_")}
    full.update(env)
    r = subprocess.run([sys.executable, "-c", "import report, regimes\n" + code], cwd=ROOT / "bench", env=full,
                       capture_output=True, text=True, timeout=60)
    return r.returncode, r.stdout, r.stderr


@pytest.mark.parametrize("env, message", [
    ({"REPORT_METHODS": "pt,foo"}, "report: REPORT_METHODS: foo is not one of bdpt, pt,"),
    ({"REPORT_SCENES": "cornell"}, "report: REPORT_SCENES: cornell is not one of"),
    ({"REPORT_SKIP": "stability,cycles"}, "report: REPORT_SKIP: cycles is not one of failures, stability"),
    ({"REPORT_METHODS": ","}, "report: REPORT_METHODS: empty is not one of"),
    ({"REPORT_METHODS": "restir_sss", "REPORT_SCENES": "cornell-box"},
     "report: REPORT_METHODS: none of these methods is measured on the REPORT_SCENES"),
    ({"REPORT_PARAMS": "{"}, "report: REPORT_PARAMS is not JSON:"),
    ({"REPORT_PARAMS": '{"restir_pt": 3}'}, "report: REPORT_PARAMS must be an object of method name to an object"),
    ({"REPORT_PARAMS": '{"restir_ptt": {}}'}, "report: REPORT_PARAMS/restir_ptt: not a method the report measures"),
])
def test_bad_configuration_is_refused_by_name(env, message):
    rc, _, err = report_module(env, "")
    assert rc == 1 and err.strip().splitlines()[-1].startswith(message), err


def test_filters_and_output_folder():
    rc, out, err = report_module({"REPORT_SCENES": "translucent,cornell-box", "REPORT_METHODS": "restir_sss,pt",
                                  "REPORT_SKIP": "failures", "REPORT_OUT": "build/try/x"},
                                 "import json; print(json.dumps([report.SCENES, sorted(report.SKIP), str(report.OUT),"
                                 " report.configuration()]))")
    assert rc == 0, err
    scenes, skip, out_dir, config = json.loads(out)
    assert scenes == {"translucent": ["pt", "restir_sss"], "cornell-box": ["pt"]}
    assert skip == ["failures"] and out_dir == str(ROOT / "build" / "try" / "x")
    assert config[0].startswith("Configuration: `REPORT_SCENES=translucent,cornell-box`, `REPORT_METHODS=restir_sss,pt`")


def test_output_folder_must_be_new_empty_or_a_report(tmp_path):
    """The report replaces its folder's charts: a folder holding anything but an earlier report is
    refused, so nothing of it is deleted."""
    other = tmp_path / "other"
    other.mkdir()
    (other / "figure.svg").write_text("<svg/>")
    rc, _, err = report_module({"REPORT_OUT": str(other)}, "")
    assert rc == 1 and err.strip().splitlines()[-1] == (
        f"report: REPORT_OUT: {other} holds files that are not a report's; name a new or empty folder"), err
    assert (other / "figure.svg").exists()
    earlier = tmp_path / "earlier"
    earlier.mkdir()
    (earlier / "README.md").write_text("# Speed against accuracy: the report\n")
    (earlier / "x_real-time_mape.svg").write_text("<svg/>")
    for folder in (earlier, tmp_path / "new"):
        rc, out, err = report_module({"REPORT_OUT": str(folder)}, "print(report.OUT)")
        assert rc == 0 and out.strip() == str(folder), err


def test_defaults_measure_everything_into_docs_report():
    rc, out, err = report_module({}, "import json; print(json.dumps([report.SCENES == report.ALL_SCENES,"
                                     " sorted(report.SKIP), str(report.OUT), report.configuration(), regimes.EXTRA_PARAMS]))")
    assert rc == 0, err
    assert json.loads(out) == [True, [], str(ROOT / "docs" / "report"), [], {}]


def test_params_reach_every_session_beneath_the_rows_own():
    """A session's parameters: REPORT_PARAMS's for its method, then the row's (the ladder's value),
    which win; a converge row's session asks for the converge profile, beneath both; other
    methods' sessions are untouched."""
    code = """
import json
class D:
    def __init__(self): self.bodies = []
    def req(self, method, path, json_body=None, **kw):
        self.bodies.append(json_body)
        class R:
            status = 201
            def json(self): return {"href": "/v1/sessions/1", "memory_bytes": 0}
        return R()
d = D()
regimes.Session(d, "cornell-box", "restir_pt", {"spatial_neighbors": 6}, 0, 16, ".")
regimes.Session(d, "cornell-box", "restir_pt", {}, 0, 16, ".", "converge")
regimes.Session(d, "cornell-box", "pt", {"spp": 4}, 0, 16, ".")
print(json.dumps([[b["params"], b.get("profile")] for b in d.bodies]))
"""
    rc, out, err = report_module({"REPORT_PARAMS": json.dumps({"restir_pt": {"spatial_neighbors": 99, "temporal": True,
                                                                            "spatial_radius": 5}})}, code)
    assert rc == 0, err
    assert json.loads(out) == [[{"spatial_neighbors": 6, "temporal": True, "spatial_radius": 5}, None],
                               [{"spatial_neighbors": 99, "temporal": True, "spatial_radius": 5}, "converge"],
                               [{"spp": 4}, None]]


def test_a_frames_time_is_its_cpu_time_over_its_threads():
    """regimes.frame_ms, and the per-method benches' Daemon.frame_ms: the daemon's render_cpu_ms
    over the frame's threads (the wall time with every thread busy, which other work on the
    machine does not stretch), and render_ms from a daemon that reports no CPU time."""
    code = """
import json
import daemon
frames = [{"render_ms": 100.0, "render_cpu_ms": 150.0, "threads": 2},
          {"render_ms": 100.0, "render_cpu_ms": 30.0, "threads": 1},
          {"render_ms": 100.0, "threads": 2}]
d = daemon.Daemon.__new__(daemon.Daemon)
d.frame = lambda session: frames[session]
print(json.dumps([[regimes.frame_ms(f) for f in frames], [d.frame_ms(i) for i in range(3)]]))
"""
    rc, out, err = report_module({}, code)
    assert rc == 0, err
    assert json.loads(out) == [[75.0, 30.0, 100.0]] * 2


def test_the_cli_benches_time_a_frame_by_its_cpu_time():
    """cputime.cli_frame_ms, as bench/restir_pt.py, bench/bdpt.py, bench/restir_bdpt.py,
    bench/sms.py and bench/report.py's failure case of the prior time a `restir render --json`
    summary: the session's cpu_ms over its threads and frames, never its wall time_ms; the frame
    after a warm-up by its own last_frame_cpu_ms, never the session's mean. One thread when the
    summary names none (as frame_time_ms)."""
    code = """
import json
import cputime
st = {"time_ms": 90.0, "cpu_ms": 160.0, "last_frame_cpu_ms": 60.0, "threads": 2}
one = {"time_ms": 90.0, "cpu_ms": 160.0, "last_frame_cpu_ms": 60.0}
print(json.dumps([cputime.cli_frame_ms(st, 4), cputime.cli_frame_ms(st, last_frame=True),
                  cputime.cli_frame_ms(st), cputime.cli_frame_ms(one, last_frame=True)]))
"""
    rc, out, err = report_module({}, code)
    assert rc == 0, err
    assert json.loads(out) == [20.0, 30.0, 80.0, 60.0]


@pytest.mark.parametrize("args, env, message", [
    (["[1]"], {}, "sweep: '[1]': parameters must be a JSON object (not an object)"),
    (["{"], {}, "sweep: '{': parameters must be a JSON object (Expecting property name"),
    (["{}"], {"SWEEP_BASELINES": "bdpt sms:[]"}, "sweep: SWEEP_BASELINES 'sms:[]': parameters must be a JSON object"),
    (["{}"], {"SWEEP_BASELINES": "sms:{spp}"}, "sweep: SWEEP_BASELINES 'sms:{spp}': parameters must be a JSON object"),
])
def test_sweep_refuses_parameters_that_are_not_an_object(args, env, message):
    """bench/sweep.py names the configuration or the SWEEP_BASELINES entry that is not a JSON object,
    and stops before rendering anything (no reference: the scene named does not exist either)."""
    full = {k: v for k, v in os.environ.items() if not k.startswith("SWEEP_")}
    full.update(env)
    r = subprocess.run([sys.executable, str(ROOT / "bench" / "sweep.py"), "no-such-scene", "restir_sms", *args],
                       env=full, capture_output=True, text=True, timeout=60)
    assert r.returncode == 1 and r.stderr.strip().startswith(message), r.stderr


def test_each_method_is_measured_before_its_baselines():
    """bench/report.py's measure_order: pt first (its times are the budgets), and every method
    before each other baseline its ratio is read against (ratios.PAIRS), on every scene."""
    rc, out, err = report_module({}, "import json; print(json.dumps({s: report.measure_order(ms) "
                                     "for s, ms in report.ALL_SCENES.items()}))")
    assert rc == 0, err
    pairs = {"restir_pt": ["pt"], "restir_bdpt": ["restir_pt", "bdpt"], "restir_sss": ["pt"], "restir_sms": ["sms"]}
    for scene, order in json.loads(out).items():
        assert sorted(order) == sorted(set(order)) and order[0] == "pt", (scene, order)
        for method, baselines in pairs.items():
            for b in baselines:
                if method in order and b in order and b != "pt":
                    assert order.index(method) < order.index(b), (scene, order)


def test_a_ladder_reaches_past_every_time_a_table_reads_it_at():
    """bench/report.py's ladder_reach: pt's largest real-time budget (its 16-spp frame), or the
    default frame of a method compared with this one if longer; pt's 64-spp image converging; no
    limit for pt itself or without pt's rows."""
    code = """import json
rows = [{"method": "pt", "regime": g, "variant": "", "setting": s, "ms": (10.0 if g == "real-time" else 11.0) * s}
        for g in ("real-time", "converge") for s in (1, 2, 4, 8, 16, 32, 64)]
rows += [{"method": "restir_bdpt", "regime": "real-time", "variant": "", "setting": "auto", "ms": 500.0},
         {"method": "restir_bdpt", "regime": "real-time", "variant": "", "setting": "2x", "ms": 900.0},
         {"method": "restir_bdpt", "regime": "real-time", "variant": "moving camera", "setting": "auto", "ms": 950.0},
         {"method": "restir_sms", "regime": "real-time", "variant": "", "setting": 1, "ms": 100.0}]
print(json.dumps([report.ladder_reach(rows, m) for m in ("restir_pt", "bdpt", "sms", "sms_ssp", "pt")]
                 + [report.ladder_reach([], "sms")]))"""
    rc, out, err = report_module({}, code)
    assert rc == 0, err
    both = {"real-time": 500.0, "converge": 704.0}
    alone = {"real-time": 160.0, "converge": 704.0}
    assert json.loads(out) == [both, both, alone, alone, None, None]
