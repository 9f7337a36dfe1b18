"""References and jobs as resources (protocol/API.md, "References" and "Animation jobs"): listing,
fetching and deleting references, Idempotency-Key on reference renders, listing a session's
jobs and which of a finished job's frames are still kept; the process and build lines of
GET /metrics; and that openapi.yaml documents exactly the daemon's routes.

One daemon with a short frame ring (--frames-kept 3) serves the file; images are 8x8."""
import http.client
import json
import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from conftest import build_commit
from daemon import BIN as DAEMON_BIN, Daemon
from test_daemon import assert_problem, new_session, wait_job, write_exr

ROOT = Path(__file__).resolve().parent.parent
CORNELL = "/v1/scenes/cornell-box"
FRAMES_KEPT = 3


@pytest.fixture(scope="module")
def daemon(tmp_path_factory):
    d = Daemon(tmp_path_factory.mktemp("resources") / "data", "--threads", "2", "--frames-kept", FRAMES_KEPT)
    yield d
    rc, _ = d.stop()
    assert rc == 0, d.stderr()[-3000:]


def references_used(d):
    return d.req("GET", "/v1/limits").json()["memory_used"]["references"]


def upload_reference(d, tmp_path, name, value=0.25, size=8):
    data = write_exr(tmp_path / f"{name}.exr", np.full((size, size, 3), value, np.float32))
    r = d.req("PUT", f"{CORNELL}/references/{name}", body=data, headers={"Content-Type": "image/x-exr"})
    assert r.status in (200, 201), repr(r)


def listed(d, scene="cornell-box"):
    r = d.req("GET", f"/v1/scenes/{scene}/references")
    assert r.status == 200 and r.header("Content-Type") == "application/json", repr(r)
    return {x["name"]: x for x in r.json()["references"]}


# ---- references ----

def test_references_list_get_delete_credit_the_budget(daemon, tmp_path):
    """A built-in scene's references are listed with their size, how they were made, their bytes
    and an href that fetches them; DELETE removes one (204, then 404) and gives its bytes back."""
    assert daemon.req("GET", CORNELL).json()["builtin"] is True
    before = references_used(daemon)
    upload_reference(daemon, tmp_path, "up8")
    s = new_session(daemon, width=8, height=8, params={"spp": 1})
    r = daemon.req("POST", s["href"] + "/references/pt8", json_body={"spp": 16})
    assert r.status == 202, repr(r)
    wait_job(daemon, r.header("Location"))
    refs = listed(daemon)
    up, pt = refs["up8"], refs["pt8"]
    assert {k: up[k] for k in ("width", "height", "spp", "method", "bytes", "href")} == \
        {"width": 8, "height": 8, "spp": 0, "method": None, "bytes": 8 * 8 * 12, "href": f"{CORNELL}/references/up8"}
    assert (pt["spp"], pt["method"], pt["bytes"]) == (16, "pt", 8 * 8 * 12)
    for x in (up, pt):
        created = time.mktime(time.strptime(x["created"], "%Y-%m-%dT%H:%M:%SZ")) - time.timezone
        assert abs(created - time.time()) < 120, x
        got = daemon.req("GET", x["href"], headers={"Accept": "application/json"})
        assert got.status == 200 and got.json()["name"] == x["name"], repr(got)
    assert references_used(daemon) == before + 2 * 768

    r = daemon.req("DELETE", f"{CORNELL}/references/up8")
    assert r.status == 204 and r.body == b"", repr(r)
    assert references_used(daemon) == before + 768
    assert "up8" not in listed(daemon) and "pt8" in listed(daemon)
    body = assert_problem(daemon.req("GET", f"{CORNELL}/references/up8"), 404, "not-found")
    assert body["detail"] == "scene 'cornell-box' has no reference 'up8'"
    body = assert_problem(daemon.req("DELETE", f"{CORNELL}/references/up8"), 404, "not-found")
    assert body["detail"] == "scene 'cornell-box' has no reference 'up8'"
    assert daemon.req("DELETE", f"{CORNELL}/references/pt8").status == 204
    assert references_used(daemon) == before
    assert daemon.req("DELETE", s["href"]).status == 204


def test_references_of_an_unknown_scene(daemon):
    assert_problem(daemon.req("GET", "/v1/scenes/no-such-scene/references"), 404, "scene-not-loaded")
    assert_problem(daemon.req("DELETE", "/v1/scenes/no-such-scene/references/x"), 404, "scene-not-loaded")
    assert_problem(daemon.req("DELETE", f"{CORNELL}/references/bad%20name"), 400, "bad-id")


def test_a_job_keeps_its_reference_after_delete(daemon, tmp_path):
    """An animation retains its reference from submission: deleting the reference while the job
    runs takes it out of the listing, and every frame is still measured against it. Its bytes
    stay in the budget while the job holds the pixels, and go back when the job ends."""
    before = references_used(daemon)
    upload_reference(daemon, tmp_path, "held", value=0.5)
    s = new_session(daemon, width=8, height=8, params={"spp": 256})
    r = daemon.req("POST", s["href"] + "/renders", json_body={"animation": {"fps": 10, "frames": 100}, "reference": "held"})
    assert r.status == 202, repr(r)
    assert daemon.req("DELETE", f"{CORNELL}/references/held").status == 204
    job = daemon.req("GET", r.header("Location")).json()
    assert job["status"] in ("queued", "running") and job["progress"]["frames_done"] < 100, job
    assert "held" not in listed(daemon)
    assert references_used(daemon) == before + 768
    job = wait_job(daemon, r.header("Location"))
    assert references_used(daemon) == before
    assert job["reference"] == "held"
    series = daemon.req("GET", r.header("Location") + "/metrics").json()["series"]
    assert len(series) == 100 and all(row["rmse"] is not None and row["rmse"] > 0 for row in series), series
    assert daemon.req("DELETE", s["href"]).status == 204


def sessions_used(d):
    return d.req("GET", "/v1/limits").json()["memory_used"]["sessions"]


def test_a_reference_job_cancelled_in_its_last_pass_stores_nothing(daemon):
    """Deleting the session while its reference job renders the last pass cancels the job: the
    reference is never stored, so a client that deletes the session and then the reference
    leaves nothing behind. (The session's bytes go back when the job lets go of it.)"""
    sessions_before, refs_before = sessions_used(daemon), references_used(daemon)
    s = new_session(daemon, width=8, height=8, params={"spp": 1})
    r = daemon.req("POST", s["href"] + "/references/late", json_body={"spp": 65536})
    assert r.status == 202, repr(r)
    while True:
        job = daemon.req("GET", r.header("Location")).json()
        assert job["status"] in ("queued", "running"), job
        if job["progress"]["frames_done"] == job["progress"]["frames_total"] - 1:
            break
        time.sleep(0.002)
    assert daemon.req("DELETE", s["href"]).status == 204
    deadline = time.monotonic() + 60
    while sessions_used(daemon) != sessions_before:
        assert time.monotonic() < deadline, "the reference job never let go of its session"
        time.sleep(0.02)
    assert "late" not in listed(daemon)
    assert references_used(daemon) == refs_before


def test_reference_post_idempotency_key(daemon):
    """The same key and body give the first job again and render nothing more; the same key
    with another body (or another name) is a 409, as for animation jobs."""
    s = new_session(daemon, width=8, height=8, params={"spp": 1})
    key = {"Idempotency-Key": f"ref-{time.monotonic_ns()}"}
    first = daemon.req("POST", s["href"] + "/references/idem", json_body={"spp": 16}, headers=key)
    assert first.status == 202, repr(first)
    again = daemon.req("POST", s["href"] + "/references/idem", json_body={"spp": 16}, headers=key)
    assert again.status == 202 and again.json()["id"] == first.json()["id"], repr(again)
    assert again.header("Location") == first.header("Location")
    jobs = daemon.req("GET", s["href"] + "/renders").json()["renders"]
    assert [j["id"] for j in jobs] == [first.json()["id"]], jobs
    job_id = first.json()["id"]
    for path, body in (("/references/idem", {"spp": 32}), ("/references/other", {"spp": 16}), ("/renders", None)):
        body = body or {"animation": {"fps": 10, "frames": 1}}
        r = daemon.req("POST", s["href"] + path, json_body=body, headers=key)
        problem = assert_problem(r, 409, "conflict", "Idempotency-Key", where=path)
        assert problem["detail"] == (f"Idempotency-Key '{key['Idempotency-Key']}' was sent with another request, "
                                     f"which made job '{job_id}'; use a new key")
    wait_job(daemon, first.header("Location"))
    assert len(daemon.req("GET", s["href"] + "/renders").json()["renders"]) == 1
    assert daemon.req("DELETE", f"{CORNELL}/references/idem").status == 204
    assert daemon.req("DELETE", s["href"]).status == 204


def post_at_once(d, path, body, headers, n):
    """n POSTs sent back to back on connections opened beforehand, so they overlap in the
    daemon; their answers in order."""
    conns = [http.client.HTTPConnection("127.0.0.1", d.port, timeout=60) for _ in range(n)]
    data = json.dumps(body).encode()
    try:
        for c in conns:
            c.connect()
        for c in conns:
            c.request("POST", path, body=data, headers={"Content-Type": "application/json", **headers})
        return [(r.status, json.loads(r.read())) for r in (c.getresponse() for c in conns)]
    finally:
        for c in conns:
            c.close()


@pytest.mark.concurrency
@pytest.mark.parametrize("path, body", [("/references/together", {"spp": 16}),
                                        ("/renders", {"animation": {"fps": 10, "frames": 2}})])
def test_requests_sent_at_once_with_one_key_make_one_job(daemon, path, body):
    """Requests under one Idempotency-Key that arrive together all get the same job: one of them
    makes it, the others are answered with it, none gets a 409."""
    s = new_session(daemon, width=8, height=8, params={"spp": 1})
    rounds = 10
    for round in range(rounds):
        key = f"together-{round}-{time.monotonic_ns()}"
        answers = post_at_once(daemon, s["href"] + path, body, {"Idempotency-Key": key}, 6)
        assert [status for status, _ in answers] == [202] * 6, answers
        assert len({job["id"] for _, job in answers}) == 1, answers
        wait_job(daemon, answers[0][1]["location"])
    assert len(daemon.req("GET", s["href"] + "/renders").json()["renders"]) == rounds
    if path.startswith("/references/"):
        assert daemon.req("DELETE", f"{CORNELL}{path}").status == 204
    assert daemon.req("DELETE", s["href"]).status == 204


# ---- jobs ----

def test_renders_list_and_evicted_frames(daemon):
    """GET …/renders lists the session's jobs; a finished job offers only the frames the session
    still keeps (the last FRAMES_KEPT), names their range, and counts the evicted ones."""
    s = new_session(daemon, width=8, height=8, params={"spp": 1})
    assert daemon.req("GET", s["href"] + "/renders").json() == {"renders": []}
    r = daemon.req("POST", s["href"] + "/renders", json_body={"animation": {"fps": 10, "frames": 5}})
    assert r.status == 202, repr(r)
    loc = r.header("Location")
    job = wait_job(daemon, loc)
    assert job["location"] == loc
    assert job["frames"] == [f"{s['href']}/frames/{n}" for n in (2, 3, 4)], job
    assert job["frames_kept"] == [2, 4] and job["frames_evicted"] == 2, job
    for href in job["frames"]:
        assert daemon.req("GET", href).status == 200, href
    assert_problem(daemon.req("GET", f"{s['href']}/frames/1"), 410, "frame-evicted")

    jobs = daemon.req("GET", s["href"] + "/renders").json()["renders"]
    assert len(jobs) == 1 and jobs[0]["id"] == job["id"] and jobs[0]["location"] == loc, jobs
    assert jobs[0]["status"] == "done" and jobs[0]["progress"] == {"frames_done": 5, "frames_total": 5}

    # A synchronous frame pushes one more of the job's frames out; a reset all of them.
    assert daemon.req("POST", s["href"] + "/frames", headers={"Accept": "application/json"}).status == 200
    job = daemon.req("GET", loc).json()
    assert job["frames_kept"] == [3, 4] and job["frames_evicted"] == 3 and len(job["frames"]) == 2, job
    assert daemon.req("POST", s["href"] + "/reset").status == 204
    job = daemon.req("GET", loc).json()
    assert job["frames"] == [] and job["frames_kept"] is None and job["frames_evicted"] == 5, job
    assert daemon.req("DELETE", s["href"]).status == 204


def test_renders_list_of_unknown_session(daemon):
    body = assert_problem(daemon.req("GET", f"{CORNELL}/sessions/nope/renders"), 404, "not-found")
    assert body["detail"] == "scene 'cornell-box' has no session 'nope'"


# ---- the Python client ----

def test_client_metrics_leaves_no_reference_and_takes_host_port(daemon, tmp_path):
    """restir.py metrics against the real daemon, named as host:port without a scheme: the CSV
    has a row per frame, and neither the reference it rendered nor its session is left."""
    out = tmp_path / "m.csv"
    before = set(listed(daemon))
    sessions = len(daemon.req("GET", f"{CORNELL}/sessions").json()["sessions"])
    run = subprocess.run([sys.executable, str(ROOT / "clients" / "python" / "restir.py"), "-q",
                          "--server", f"127.0.0.1:{daemon.port}", "metrics", "cornell-box", "--size", "8x8",
                          "--reference-spp", "16", "--frames", "2", "-o", str(out)],
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    assert out.read_text().splitlines()[0].startswith("frame,time_s,render_ms,mape,rmse,relmse,converge_")
    assert len(out.read_text().splitlines()) == 3
    assert set(listed(daemon)) == before
    assert len(daemon.req("GET", f"{CORNELL}/sessions").json()["sessions"]) == sessions


# ---- /metrics ----

def metric(text, name):
    m = re.search(rf"^{name} (\S+)$", text, re.M)
    assert m, f"no {name} in\n{text}"
    assert f"# TYPE {name} " in text
    return float(m.group(1))


def test_metrics_process_and_build_info(daemon):
    text = daemon.req("GET", "/metrics").body.decode()
    pid = daemon.proc.pid
    status = Path(f"/proc/{pid}/status").read_text()
    rss_kb = int(re.search(r"VmRSS:\s+(\d+) kB", status).group(1))
    vm_kb = int(re.search(r"VmSize:\s+(\d+) kB", status).group(1))
    rss = metric(text, "process_resident_memory_bytes")
    assert 0.5 * rss_kb * 1024 < rss < 2 * rss_kb * 1024, (rss, rss_kb)
    assert metric(text, "process_virtual_memory_bytes") == pytest.approx(vm_kb * 1024, rel=0.2)
    started = metric(text, "process_start_time_seconds")
    assert started == pytest.approx(Path(f"/proc/{pid}").stat().st_mtime, abs=600)
    assert time.time() - 3600 < started <= time.time() + 1
    assert metric(text, "process_cpu_seconds_total") > 0
    fds = metric(text, "process_open_fds")
    assert 3 <= fds <= len(list(Path(f"/proc/{pid}/fd").iterdir())) + 8, fds
    assert metric(text, "process_max_fds") >= fds
    info = re.findall(r'^restird_build_info\{version="([^"]+)",commit="([^"]+)"\} 1$', text, re.M)
    header = (ROOT / "server" / "version.h").read_text()
    version = re.search(r'#define RESTIRD_VERSION "([^"]+)"', header).group(1)
    assert info == [(version, build_commit(DAEMON_BIN))], text
    # The Python client carries the same release (its package's version is this __version__).
    client = (ROOT / "clients" / "python" / "restir.py").read_text()
    assert re.findall(r'^__version__ = "([^"]+)"$', client, re.M) == [version]


# ---- the API description ----

def route_table():
    """The daemon's routes (server/api.c) as {path with {} for every id: set of methods}."""
    src = (ROOT / "server" / "api.c").read_text()
    table = src[src.index("api_routes[] = {"):]
    table = table[:table.index("};")]
    routes = {}
    for pattern, methods in re.findall(r'\{"(/[^"]*)", \{([^}]*)\}', table):
        routes[re.sub(r"(?<=/)[*#@](?=/|$)", "{}", pattern)] = set(re.findall(r'"([A-Z]+)"', methods))
    return routes


def test_openapi_paths_agree_with_the_route_table():
    """Every route and method the daemon serves is described in openapi.yaml, and nothing else
    (…/frames/latest is one of …/frames/{n})."""
    yaml = pytest.importorskip("yaml")
    doc = yaml.safe_load((ROOT / "protocol" / "openapi.yaml").read_text())
    documented = {}
    for path, item in doc["paths"].items():
        path = re.sub(r"\{[^}]+\}", "{}", path.replace("/frames/latest", "/frames/{n}"))
        documented.setdefault(path, set()).update(m.upper() for m in item if m in ("get", "put", "post", "delete"))
    assert documented == route_table()
