"""End-to-end tests of the render daemon build/restird against protocol/API.md (tests/README.md).

The real daemon runs on an ephemeral loopback port (`--listen 127.0.0.1:0`, the port is read from
its first stdout line). One module-scoped daemon serves most tests; tests that restart, signal or
need other limits start their own. EXR answers are decoded with OpenImageIO, a reader independent
of the daemon's writer. Expectations follow API.md: where the daemon disagrees, the test fails.

Images are small (16x16 to 64x64 at 1-8 spp) except the few renders that must take a while (a
frame that has to be in progress while other requests arrive); the whole file runs in well under
two minutes on two cores."""
import http.client
import json
import os
import sys
import re
import socket
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import pytest

from conftest import render
from daemon import Daemon

ROOT = Path(__file__).resolve().parent.parent
P = "urn:restird:problem:"
CORNELL = "/v1/scenes/cornell-box"
CORNELL_MEAN = np.array([0.196, 0.127, 0.036])  # full-image mean of scenes/cornell-box (pt)
CORNELL_CAMERA = {"position": [278, 273, -800], "look_at": [278, 273, 0], "up": [0, 1, 0], "fov_deg": 39.3077}
TETRA_PLY = (ROOT / "tests" / "meshes" / "tetra.ply").read_bytes()
J = {"Content-Type": "application/json"}
LIMIT_KEYS = ["max_side", "max_pixels", "max_spp", "max_frames", "max_keys", "max_sessions", "frames_kept",
              "max_json_body", "max_asset_body", "max_reference_body", "render_slots", "render_queue",
              "job_queue", "connection_limit", "per_ip_connection_limit", "connection_timeout_s", "memory_budget",
              "max_session_bytes", "max_work", "head_timeout_s", "min_body_rate"]

# Limits of the shared daemon (small where a test needs to cross them cheaply).
MAX_JSON_BODY = 16384
MAX_ASSET_BODY = 1 << 20


# ---- daemons ----

def start_daemon(tmp_path_factory, name, *extra):
    return Daemon(tmp_path_factory.mktemp(name) / "data", *extra)


@pytest.fixture(scope="module")
def daemon(tmp_path_factory):
    d = start_daemon(tmp_path_factory, "main", "--threads", "2", "--max-json-body", MAX_JSON_BODY,
                     "--max-asset-body", MAX_ASSET_BODY, "--max-reference-body", 4 << 20)
    yield d
    rc, _ = d.stop()
    assert rc == 0, d.stderr()[-3000:]


# ---- helpers ----

def decode_image(data, suffix):
    """Decodes EXR or PNG bytes with OpenImageIO: (H x W x C float64 array, ImageSpec)."""
    with tempfile.NamedTemporaryFile(suffix=suffix) as f:
        f.write(data)
        f.flush()
        inp = oiio.ImageInput.open(f.name)
        assert inp is not None, oiio.geterror()
        try:
            spec = inp.spec()
            pixels = inp.read_image(oiio.FLOAT)
        finally:
            inp.close()
    assert pixels is not None, oiio.geterror()
    return np.asarray(pixels, dtype=np.float64).reshape(spec.height, spec.width, spec.nchannels), spec


def exr_rgb(data):
    img, spec = decode_image(data, ".exr")
    names = list(spec.channelnames)
    assert {"R", "G", "B"} <= set(names), names
    return np.stack([img[..., names.index(c)] for c in "RGB"], axis=-1)


def write_exr(path, pixels, compression="zip"):
    h, w, c = pixels.shape
    spec = oiio.ImageSpec(w, h, c, oiio.FLOAT)
    spec.attribute("compression", compression)
    out = oiio.ImageOutput.create(str(path))
    assert out is not None and out.open(str(path), spec), oiio.geterror()
    assert out.write_image(np.ascontiguousarray(pixels, dtype=np.float32))
    out.close()
    return Path(path).read_bytes()


def assert_problem(r, status, slug, field=None, where=""):
    ctx = f"{where}\n{r!r}"
    assert r.status == status, ctx
    assert r.header("Content-Type", "").split(";")[0].strip() == "application/problem+json", ctx
    body = r.json()
    assert body["type"] == P + slug, ctx
    assert body["status"] == status, ctx
    assert isinstance(body.get("title"), str) and body["title"], ctx
    assert isinstance(body.get("detail"), str), ctx
    assert isinstance(body.get("instance"), str), ctx
    if field is not None:
        assert body.get("field") == field, ctx
    assert r.header("X-Request-Id") and r.header("X-Served-By"), ctx
    return body


def new_session(d, scene="cornell-box", **body):
    r = d.req("POST", f"/v1/scenes/{scene}/sessions", json_body=body)
    assert r.status == 201, repr(r)
    s = r.json()
    assert r.header("Location") == s["href"], repr(r)
    return s


def post_frame(d, session, body=None, accept="image/x-exr", query="", expect=200):
    headers = {"Accept": accept} if accept else {}
    if body is None:
        r = d.req("POST", session["href"] + "/frames" + query, headers=headers)
    else:
        r = d.req("POST", session["href"] + "/frames" + query, headers=headers, json_body=body)
    if expect is not None:
        assert r.status == expect, repr(r)
    return r


def frame_rgb(d, session, body=None, query=""):
    return exr_rgb(post_frame(d, session, body, query=query).body)


def wait_job(d, href, done=("done",), timeout=90):
    deadline = time.monotonic() + timeout
    while True:
        r = d.req("GET", href)
        assert r.status == 200, repr(r)
        job = r.json()
        if job["status"] in done:
            return job
        assert job["status"] in ("queued", "running"), job
        assert time.monotonic() < deadline, f"job still {job['status']} after {timeout} s: {job}"
        time.sleep(0.05)


def wait_busy(d, session, thread, timeout=30):
    """Polls the session until it reports busy (a frame in progress); fails if the frame ended first."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        s = d.req("GET", session["href"]).json()
        if s["busy"]:
            return s
        assert thread.is_alive(), "the slow frame finished before the session was seen busy"
        time.sleep(0.005)
    raise AssertionError("the session never reported busy")


def block_means(img, b=4):
    h, w, c = img.shape
    return img[: h - h % b, : w - w % b].reshape(h // b, b, w // b, b, c).mean(axis=(1, 3))


def block_diff(a, b):
    return float(np.mean(np.abs(block_means(a) - block_means(b))))


def cornell_scene(**light):
    scene = json.loads((ROOT / "scenes" / "cornell-box" / "scene.json").read_text())
    if light:
        scene["materials"]["light"].update(light)
    return scene


def mesh_scene(file="tetra.ply", radiance=1.0):
    return {"camera": {"position": [0, 0, -6], "look_at": [0, 0, 0], "up": [0, 1, 0], "fov_deg": 40},
            "materials": {"w": {"type": "diffuse", "albedo": [0.5, 0.5, 0.5]}},
            "shapes": [{"type": "mesh", "material": "w", "file": file}],
            "environment": {"radiance": [radiance] * 3}}


def put_mesh_scene(d, sid):
    """Uploads tests/meshes/tetra.ply and then mesh_scene() under `sid`; returns the scene answer."""
    r = d.req("PUT", f"/v1/scenes/{sid}/assets/tetra.ply", body=TETRA_PLY, headers={"Content-Type": "model/ply"})
    assert r.status == 201, repr(r)
    return d.req("PUT", f"/v1/scenes/{sid}", json_body=mesh_scene())


def metric_value(text, name, labels=None):
    """The value of one Prometheus sample (None when absent)."""
    for line in text.splitlines():
        if line.startswith("#") or not line.strip():
            continue
        m = re.match(r"^([a-zA-Z_:][a-zA-Z0-9_:]*)(\{([^}]*)\})?\s+(\S+)$", line)
        assert m, f"not a Prometheus sample line: {line!r}"
        if m.group(1) != name:
            continue
        got = dict(re.findall(r'(\w+)="((?:[^"\\]|\\.)*)"', m.group(3) or ""))
        if labels is None or all(got.get(k) == v for k, v in labels.items()):
            return float(m.group(4))
    return None


# ---- 1. every endpoint ----

def test_healthz_readyz_and_common_headers(daemon):
    r = daemon.req("GET", "/healthz")
    assert r.status == 200 and r.json() == {"status": "ok"}, repr(r)
    assert r.header("Content-Type").startswith("application/json")
    assert re.fullmatch(r"[A-Za-z0-9_-]{1,64}", r.header("X-Request-Id") or ""), repr(r)
    assert r.header("X-Served-By") == f"127.0.0.1:{daemon.port}", repr(r)
    # A valid X-Request-Id is echoed; an invalid one is replaced by a generated one.
    r = daemon.req("GET", "/healthz", headers={"X-Request-Id": "trace-42_A"})
    assert r.header("X-Request-Id") == "trace-42_A", repr(r)
    r = daemon.req("GET", "/healthz", headers={"X-Request-Id": "bad id!"})
    assert r.status == 200 and re.fullmatch(r"[A-Za-z0-9_-]{1,64}", r.header("X-Request-Id") or ""), repr(r)
    assert r.header("X-Request-Id") != "bad id!"
    r = daemon.req("GET", "/readyz")
    assert r.status == 200 and r.json() == {"status": "ready"}, repr(r)
    # Each request is logged on stderr: time method path status bytes ms request-id.
    time.sleep(0.2)
    assert re.search(r"GET /healthz 200 \d+ [0-9.]+ trace-42_A", daemon.stderr()), daemon.stderr()[-2000:]


def test_limits_reflect_options(daemon):
    r = daemon.req("GET", "/v1/limits")
    assert r.status == 200, repr(r)
    lim = r.json()
    for key in LIMIT_KEYS:
        assert isinstance(lim.get(key), int), (key, lim)
    assert lim["max_json_body"] == MAX_JSON_BODY
    assert lim["max_asset_body"] == MAX_ASSET_BODY
    assert lim["max_side"] == 4096 and lim["max_pixels"] == 16777216 and lim["max_spp"] == 65536
    assert lim["max_frames"] == 10000 and lim["max_sessions"] == 64 and lim["frames_kept"] == 16
    assert lim["memory_budget"] == 8 << 30 and lim["max_session_bytes"] == 2 << 30
    assert set(lim["memory_used"]) == {"sessions", "scenes", "references", "uploads"}, lim


def test_openapi_document(daemon):
    r = daemon.req("GET", "/v1/openapi.yaml")
    assert r.status == 200, repr(r)
    text = r.body.decode()
    assert text.startswith("openapi:")
    try:
        import yaml
    except ImportError:
        return
    doc = yaml.safe_load(text)
    assert str(doc["openapi"]).startswith("3.1")
    assert "/v1/scenes/{scene}/sessions/{sid}/frames" in doc["paths"]


PAGE = ROOT / "clients" / "web" / "page"
UPLOT = ROOT / "clients" / "web" / "node_modules" / "uplot" / "dist"
PAGE_TYPES = {".html": "text/html; charset=utf-8", ".js": "text/javascript; charset=utf-8",
              ".css": "text/css; charset=utf-8"}


def test_preview_page_is_served_from_the_binary(daemon):
    """GET / is clients/web/page/index.html as built into the daemon; every file of the page and
    the uPlot files it imports are served under /ui/ byte for byte, with their media type and a
    strong ETag that a matching If-None-Match turns into a 304."""
    r = daemon.req("GET", "/", headers={"Accept": "text/html"})
    assert r.status == 200, repr(r)
    assert r.header("Content-Type") == PAGE_TYPES[".html"]
    index = (PAGE / "index.html").read_bytes()
    assert r.body == index
    assert "default-src 'self'" in r.header("Content-Security-Policy", "")
    assert r.header("X-Content-Type-Options") == "nosniff"
    assert r.header("Cache-Control") == "no-cache"
    etag = r.header("ETag")
    assert re.fullmatch(r'"[0-9a-f]{24}"', etag), etag
    assert daemon.req("GET", "/", headers={"If-None-Match": etag}).status == 304
    assert daemon.req("GET", "/", headers={"If-None-Match": f'"other", W/{etag}'}).status == 304
    assert daemon.req("GET", "/", headers={"If-None-Match": '"other"'}).status == 200

    served = {}
    for f in sorted(PAGE.iterdir()):
        r = daemon.req("GET", f"/ui/{f.name}")
        assert r.status == 200, repr(r)
        assert r.body == f.read_bytes(), f.name
        assert r.header("Content-Type") == PAGE_TYPES[f.suffix], f.name
        served[f.name] = r
    assert served["app.js"].header("ETag") != served["api.js"].header("ETag")
    for name in ("uPlot.esm.js", "uPlot.min.css"):
        r = daemon.req("GET", f"/ui/{name}")
        assert r.status == 200, repr(r)
        assert r.body == (UPLOT / name).read_bytes()
        assert r.header("Content-Type") == PAGE_TYPES[Path(name).suffix]
    # Every file the page names is there: the document's links and the modules' imports.
    names = re.findall(r'(?:src|href)="ui/([^"]+)"', index.decode())
    for f in PAGE.glob("*.js"):
        names += re.findall(r"from '\./([^']+)'", f.read_text())
    assert "app.js" in names and "uPlot.esm.js" in names
    for name in set(names):
        assert daemon.req("GET", f"/ui/{name}").status == 200, name


@pytest.mark.parametrize("path", [
    "/ui/nope.js", "/ui/", "/ui", "/index.html", "/ui/APP.JS", "/ui/./app.js", "/ui/app.js/x",
    "/ui/../Makefile", "/ui/..%2FMakefile", "/ui/%2e%2e/Makefile", "/ui/%2e%2e%2fMakefile", "/ui/%2e%2e",
    "/ui/..", "/ui/app.js%00.png", "//etc/passwd", "/ui/%2Fetc%2Fpasswd",
])
def test_preview_page_has_no_other_files(daemon, path):
    """Only the built-in files exist: no path reaches the file system, whatever it spells."""
    assert_problem(daemon.raw("GET", path), 404, "not-found", where=path)


def test_preview_page_is_read_only(daemon):
    for method, path in (("POST", "/"), ("PUT", "/ui/app.js"), ("DELETE", "/ui/index.html")):
        r = daemon.raw(method, path)
        assert_problem(r, 405, "method-not-allowed", where=path)
        assert r.header("Allow") == "GET, HEAD"


def test_methods_registry(daemon):
    """GET /v1/methods lists every method with its parameters; each method's defaults, sent back as
    the page's form sends them (every parameter with a default), make a session that reports the
    same values, also under the converge profile (the params win over it), and a converge session
    without params reports the converge defaults the registry lists (exactly the methods that
    reuse frames have any); the Python client's spp rule follows the capabilities; and
    openapi.yaml documents each parameter with the registry's default, converge default and
    range."""
    import yaml
    sys_path_client()
    import restir
    r = daemon.req("GET", "/v1/methods")
    assert r.status == 200 and r.header("Content-Type").startswith("application/json")
    methods = r.json()["methods"]
    names = [m["name"] for m in methods]
    assert names == ["pt", "restir_pt", "bdpt", "sms", "restir_sss", "sms_ssp", "restir_bdpt", "restir_sms"]
    schemas = yaml.safe_load((ROOT / "protocol" / "openapi.yaml").read_text())["components"]["schemas"]
    schema_of = {"pt": "PtParams", "restir_pt": "RestirPtParams", "bdpt": "BdptParams", "sms": "SmsParams",
                 "restir_sss": "RestirSssParams", "sms_ssp": "SmsSspParams", "restir_bdpt": "RestirBdptParams",
                 "restir_sms": "RestirSmsParams"}
    max_spp = daemon.req("GET", "/v1/limits").json()["max_spp"]
    for m in methods:
        assert m["summary"] and set(m["capabilities"]) == {"takes_spp", "reuses_frames", "reuses_pixels",
                                                          "manifold_counters"}
        params = {p["name"]: p for p in m["params"]}
        assert ("spp" in params) == m["capabilities"]["takes_spp"], m["name"]
        if "spp" in params:
            assert params["spp"]["maximum"] == max_spp
        doc = schemas[schema_of[m["name"]]]["properties"]
        assert set(doc) == set(params), (m["name"], set(doc) ^ set(params))
        for name, p in params.items():
            d, where = doc[name], (m["name"], name)
            assert d.get("default") == (pytest.approx(p["default"]) if p["default"] is not None else None), where
            assert d.get("x-converge-default") == p.get("converge_default"), where
            if p["type"] in ("integer", "number"):
                lo = d.get("exclusiveMinimum", d.get("minimum"))
                hi = d.get("exclusiveMaximum", d.get("maximum"))
                assert lo == pytest.approx(p["minimum"]) and ("exclusiveMinimum" in d) == bool(p.get("exclusive_minimum")), where
                if name != "spp":   # openapi gives the default max_spp, the registry this daemon's
                    assert hi == pytest.approx(p["maximum"]), where
                assert ("exclusiveMaximum" in d) == bool(p.get("exclusive_maximum")), where
            if p["type"] == "string":
                assert sorted(d["enum"]) == sorted(p["choices"]), where
        sent = {n: p["default"] for n, p in params.items() if p["default"] is not None}
        converge = {n: p.get("converge_default", p["default"]) for n, p in params.items() if p["default"] is not None}
        assert (converge != sent) == m["capabilities"]["reuses_frames"], m["name"]
        for profile, body_params, expect in ((None, sent, sent), ("converge", sent, sent), ("converge", None, converge)):
            body = {"method": m["name"], "width": 8, "height": 8, "profile": profile, "params": body_params}
            r = daemon.req("POST", "/v1/scenes/refractive-slab/sessions",
                           json_body={k: v for k, v in body.items() if v is not None})
            assert r.status == 201, (m["name"], r.body[:300])
            s = r.json()
            assert set(s["params"]) == set(params) and s["profile"] == (profile or "real_time")
            for n, v in expect.items():
                if m["name"] in ("restir_pt", "restir_bdpt") and n == "spatial_radius" and v == 0:
                    v = 3  # 0 is the resolution's radius, which the session reports: at 8 x 8 the least, 3
                if m["name"] == "restir_pt" and n == "candidates" and v == 0:
                    v = 8  # 0 is the scene's count, which the session reports: 8 with refractive-slab's glass
                assert s["params"][n] == pytest.approx(v), (m["name"], profile, n)
            assert daemon.req("DELETE", s["href"]).status == 204
        # The client sends spp (without --spp) exactly to the methods whose entry takes it.
        a = restir.build_parser().parse_args(["frame", "s", "-o", "x", "--method", m["name"]])
        registry = {x["name"]: x for x in methods}
        assert ("spp" in restir._session_params(a, registry)) == m["capabilities"]["takes_spp"]


def sys_path_client():
    """Makes clients/python importable."""
    import sys
    path = str(ROOT / "clients" / "python")
    if path not in sys.path:
        sys.path.insert(0, path)


def test_metrics_prometheus(daemon):
    text = daemon.req("GET", "/metrics").body.decode()
    before = metric_value(text, "restird_requests_total", {"route": "/healthz", "code": "200"}) or 0
    for _ in range(3):
        assert daemon.req("GET", "/healthz").status == 200
    r = daemon.req("GET", "/metrics")
    assert r.status == 200, repr(r)
    assert r.header("Content-Type").startswith("text/plain"), repr(r)
    text = r.body.decode()
    after = metric_value(text, "restird_requests_total", {"route": "/healthz", "code": "200"})
    assert after is not None and after >= before + 3, (before, after)
    for family, kind in [("restird_requests_total", "counter"), ("restird_frame_render_seconds", "histogram"),
                         ("restird_sessions", "gauge"), ("restird_scenes", "gauge"),
                         ("restird_session_bytes", "gauge"), ("restird_reservoir_bytes", "gauge"),
                         ("restird_reference_bytes", "gauge"), ("restird_render_queue_depth", "gauge"),
                         ("restird_job_queue_depth", "gauge")]:
        assert re.search(rf"^# TYPE {family} {kind}$", text, re.M), f"no {kind} family {family} in /metrics; families: {re.findall(r'^# TYPE (.*)$', text, re.M)}"
    assert metric_value(text, "restird_frame_render_seconds_bucket", {"le": "+Inf"}) is not None
    assert metric_value(text, "restird_frame_render_seconds_count") is not None
    scenes = daemon.req("GET", "/v1/scenes").json()["scenes"]
    assert metric_value(text, "restird_scenes") == len(scenes)


def test_scenes_list_get_put_replace(daemon):
    r = daemon.req("GET", "/v1/scenes")
    assert r.status == 200, repr(r)
    scenes = r.json()["scenes"]
    ids = [s["id"] for s in scenes]
    assert ids == sorted(ids) and "cornell-box" in ids
    cb = next(s for s in scenes if s["id"] == "cornell-box")
    for key in ["id", "builtin", "hash", "materials", "shapes", "triangles", "emitters", "scene_bytes",
                "sessions", "assets", "href"]:
        assert key in cb, (key, cb)
    assert cb["builtin"] is True and cb["materials"] == 4 and cb["shapes"] == 16 and cb["triangles"] == 32
    assert cb["href"] == CORNELL
    r = daemon.req("GET", CORNELL)
    assert r.status == 200 and r.json()["hash"] == cb["hash"], repr(r)

    scene = cornell_scene()
    r = daemon.req("PUT", "/v1/scenes/up-scene", json_body=scene)
    assert r.status == 201, repr(r)
    first = r.json()
    assert first["id"] == "up-scene" and first["builtin"] is False and first["shapes"] == 16
    assert first["href"] == "/v1/scenes/up-scene"
    assert first.get("replaced", False) is False
    # The same content again: 200, same hash, nothing replaced.
    r = daemon.req("PUT", "/v1/scenes/up-scene", json_body=scene)
    assert r.status == 200, repr(r)
    assert r.json()["hash"] == first["hash"] and r.json().get("replaced", False) is False, repr(r)
    # Changed content: 200 replaced, a new hash.
    r = daemon.req("PUT", "/v1/scenes/up-scene", json_body=cornell_scene(emission=[1, 2, 3]))
    assert r.status == 200, repr(r)
    assert r.json()["hash"] != first["hash"], repr(r)
    assert r.json().get("replaced") is True, f"API.md: a changed scene answers 200 with \"replaced\": true\n{r!r}"
    assert daemon.req("GET", "/v1/scenes/up-scene").json()["hash"] == r.json()["hash"]
    assert "up-scene" in [s["id"] for s in daemon.req("GET", "/v1/scenes").json()["scenes"]]
    assert daemon.req("DELETE", "/v1/scenes/up-scene").status == 204


def test_assets_mesh_scene_renders(daemon):
    r = daemon.req("PUT", "/v1/scenes/mesh-scene/assets/tetra.ply", body=TETRA_PLY, headers={"Content-Type": "model/ply"})
    assert r.status == 201, repr(r)
    r = daemon.req("PUT", "/v1/scenes/mesh-scene/assets/tetra.ply", body=TETRA_PLY,
                   headers={"Content-Type": "application/octet-stream"})
    assert r.status == 200, repr(r)
    obj = (ROOT / "tests" / "meshes" / "square.obj").read_bytes()
    r = daemon.req("PUT", "/v1/scenes/mesh-scene/assets/square.obj", body=obj, headers={"Content-Type": "model/obj"})
    assert r.status == 201, repr(r)
    r = daemon.req("PUT", "/v1/scenes/mesh-scene", json_body=mesh_scene())
    assert r.status == 201, repr(r)
    sc = r.json()
    assert sc["triangles"] == 4 and sc["assets"] >= 1 and sc["builtin"] is False, sc
    s = new_session(daemon, "mesh-scene", width=24, height=24, params={"spp": 2})
    img = frame_rgb(daemon, s)
    assert img.shape == (24, 24, 3) and np.isfinite(img).all()
    # Background pixels see the environment (radiance 1); the tetrahedron (albedo 0.5) is darker.
    assert np.isclose(img[0, 0], 1.0, atol=1e-5).all(), img[0, 0]
    assert (img.mean(axis=2) < 0.75).sum() >= 10, img.mean(axis=2)
    assert daemon.req("DELETE", s["href"]).status == 204
    assert daemon.req("DELETE", "/v1/scenes/mesh-scene").status == 204


def test_delete_scene_conflict_force_and_not_loaded(daemon):
    assert daemon.req("PUT", "/v1/scenes/del-scene", json_body=cornell_scene()).status == 201
    s = new_session(daemon, "del-scene", width=16, height=16)
    assert daemon.req("GET", "/v1/scenes/del-scene").json()["sessions"] == 1
    assert_problem(daemon.req("DELETE", "/v1/scenes/del-scene"), 409, "conflict")
    r = daemon.req("DELETE", "/v1/scenes/del-scene?force=true")
    assert r.status == 204 and r.body == b"", repr(r)
    assert_problem(daemon.req("GET", "/v1/scenes/del-scene"), 404, "scene-not-loaded")
    assert_problem(daemon.req("DELETE", "/v1/scenes/del-scene"), 404, "scene-not-loaded")
    assert "del-scene" not in [x["id"] for x in daemon.req("GET", "/v1/scenes").json()["scenes"]]
    # The session keeps working on its copy of the scene.
    img = frame_rgb(daemon, s)
    assert img.shape == (16, 16, 3) and img.mean() > 0
    assert daemon.req("DELETE", s["href"]).status == 204
    # Built-in scenes are read-only.
    assert_problem(daemon.req("DELETE", CORNELL), 409, "conflict")


def test_session_create_get_list_reset_delete(daemon):
    body = {"method": "pt", "width": 24, "height": 16, "seed": 5,
            "params": {"spp": 2, "max_depth": 8, "rr_depth": 2, "nee": False, "subset": "rest", "sampler": "sobol",
                       "light_sampling": "solid_angle"}}
    s = new_session(daemon, **body)
    assert re.fullmatch(r"[A-Za-z0-9_-]{1,64}", s["id"])
    assert s["href"] == f"{CORNELL}/sessions/{s['id']}"
    assert (s["scene"], s["method"], s["width"], s["height"], s["seed"]) == ("cornell-box", "pt", 24, 16, 5)
    assert s["params"] == body["params"]
    assert s["frames_rendered"] == 0 and s["busy"] is False
    assert s["frames_kept"] == 16 and s["reservoir_bytes"] == 0
    assert s["camera"]["position"] == [278, 273, -800] and s["camera"]["look_at"] == [278, 273, 0]
    assert s["camera"]["fov_deg"] == pytest.approx(39.3077, abs=1e-4)
    assert s["buffers"]["accumulation"] == 24 * 16 * 3 * 4
    assert s["memory_bytes"] == sum(s["buffers"].values())
    r = daemon.req("GET", s["href"])
    assert r.status == 200 and r.json()["id"] == s["id"] and r.json()["params"] == body["params"], repr(r)
    r = daemon.req("GET", f"{CORNELL}/sessions")
    assert r.status == 200 and s["id"] in [x["id"] for x in r.json()["sessions"]], repr(r)

    # Defaults: an empty body is the same as {}.
    d = daemon.req("POST", f"{CORNELL}/sessions", body=b"", headers=J)
    assert d.status == 201, repr(d)
    dflt = d.json()
    assert (dflt["method"], dflt["width"], dflt["height"], dflt["seed"]) == ("pt", 256, 256, 0)
    assert dflt["params"] == {"spp": 1, "max_depth": 64, "rr_depth": 3, "nee": True, "subset": "all",
                              "sampler": "sobol", "light_sampling": "area"}
    assert dflt["buffers"]["accumulation"] == 256 * 256 * 12
    assert daemon.req("DELETE", dflt["href"]).status == 204

    for n in range(2):
        r = post_frame(daemon, s, accept="application/json")
        assert r.header("X-Frame") == str(n) and r.json()["frame"] == n
    got = daemon.req("GET", s["href"]).json()
    assert got["frames_rendered"] == 2 and got["memory_bytes"] > sum(got["buffers"].values())
    r = daemon.req("POST", s["href"] + "/reset")
    assert r.status == 204 and r.body == b"", repr(r)
    assert daemon.req("GET", s["href"]).json()["frames_rendered"] == 0
    r = post_frame(daemon, s, accept="application/json")
    assert r.header("X-Frame") == "0" and r.json()["accumulated"] == 1, repr(r)
    r = daemon.req("DELETE", s["href"])
    assert r.status == 204, repr(r)
    assert_problem(daemon.req("GET", s["href"]), 404, "not-found")
    assert_problem(daemon.req("DELETE", s["href"]), 404, "not-found")
    assert s["id"] not in [x["id"] for x in daemon.req("GET", f"{CORNELL}/sessions").json()["sessions"]]


def test_frame_exr_matches_known_cornell_mean(daemon):
    w = h = 64
    s = new_session(daemon, width=w, height=h, seed=3, params={"spp": 8})
    r = post_frame(daemon, s)
    assert r.header("Content-Type") == "image/x-exr", repr(r)
    assert r.header("X-Frame") == "0" and float(r.header("X-Render-Ms")) > 0, repr(r)
    assert r.header("Content-Location") == s["href"] + "/frames/0", repr(r)
    assert re.fullmatch(r'"[^"]+"', r.header("ETag") or ""), repr(r)
    img, spec = decode_image(r.body, ".exr")
    assert (spec.width, spec.height) == (w, h)
    assert {"R", "G", "B"} <= set(spec.channelnames) and spec.format == oiio.FLOAT
    assert np.isfinite(img).all() and (img >= 0).all()
    a = exr_rgb(r.body)
    b = frame_rgb(daemon, s)  # a second, independent frame of the same state
    assert not np.array_equal(a, b)
    # Noise from the two independent frames (the deterministic parts, e.g. the light, cancel).
    npix = w * h
    mean = (a.mean(axis=(0, 1)) + b.mean(axis=(0, 1))) / 2
    se = (a - b).reshape(-1, 3).std(axis=0) / (2 * np.sqrt(npix))
    tol = 4 * se + 0.003
    assert tol[0] < 0.1 * CORNELL_MEAN[0], f"test not discriminative: tolerance {tol}"
    assert (np.abs(mean - CORNELL_MEAN) < tol).all(), f"mean {mean}, expected {CORNELL_MEAN} +- {tol}"
    # Sanity: the same check would reject a 10 % brighter image.
    assert not (np.abs(1.1 * mean - CORNELL_MEAN) < tol).all()
    # Half pixels: same image to half precision.
    r = daemon.req("GET", s["href"] + "/frames/0?pixel=half")
    assert r.status == 200 and r.header("Content-Type") == "image/x-exr", repr(r)
    hi, hspec = decode_image(r.body, ".exr")
    assert hspec.format == oiio.HALF
    np.testing.assert_allclose(exr_rgb(r.body), a, rtol=1e-3, atol=1e-4)
    assert daemon.req("DELETE", s["href"]).status == 204


def test_frame_png_and_json(daemon):
    s = new_session(daemon, width=32, height=24, params={"spp": 2})
    r = post_frame(daemon, s, accept="image/png")
    assert r.header("Content-Type") == "image/png", repr(r)
    assert r.body[:8] == b"\x89PNG\r\n\x1a\n"
    img, spec = decode_image(r.body, ".png")
    assert (spec.width, spec.height) == (32, 24) and spec.nchannels in (3, 4)
    assert img.max() > 0
    r = daemon.req("GET", s["href"] + "/frames/0?exposure=-2&tonemap=aces", headers={"Accept": "image/png"})
    assert r.status == 200 and r.body[:8] == b"\x89PNG\r\n\x1a\n", repr(r)
    darker, _ = decode_image(r.body, ".png")
    assert darker[..., :3].mean() < img[..., :3].mean()

    r = post_frame(daemon, s, accept="application/json")
    assert r.header("Content-Type").startswith("application/json"), repr(r)
    st = r.json()
    for key in ["frame", "time_s", "render_ms", "render_cpu_ms", "scene_update_ms", "rays", "rays_per_s", "samples",
                "nonfinite", "threads", "accumulated", "href"]:
        assert key in st, (key, st)
    # The CPU time of all the frame's threads: some, and no more than its threads could spend in
    # its wall-clock time (the CPU reading spans a little more of the frame than render_ms's).
    assert 0 < st["render_cpu_ms"] <= st["threads"] * (st["render_ms"] + 5.0), st
    assert st["frame"] == 1 and r.header("X-Frame") == "1"
    assert st["samples"] == 32 * 24 * 2 and st["rays"] >= st["samples"] and st["rays_per_s"] > 0
    assert st["nonfinite"] == 0 and st["threads"] == 2 and st["accumulated"] == 2
    assert st["render_ms"] > 0 and st["href"] == s["href"] + "/frames/1" == r.header("Content-Location")
    assert "metrics" not in st
    r = post_frame(daemon, s, {"time_s": 0.25}, accept="application/json")
    assert r.json()["time_s"] == pytest.approx(0.25), repr(r)
    assert daemon.req("DELETE", s["href"]).status == 204


def test_light_changes(daemon):
    s = new_session(daemon, width=32, height=32, seed=5, params={"spp": 4})
    a = frame_rgb(daemon, s)
    b = frame_rgb(daemon, s)
    noise = block_diff(a, b)
    base = (a.mean() + b.mean()) / 2
    se = (a - b).std() / np.sqrt(2 * a.size)  # standard error of one frame's mean
    # Emission 0 on the only light: the box goes dark, and the change stays for later frames.
    dark = frame_rgb(daemon, s, {"lights": {"ceiling_light": {"emission": [0, 0, 0]}}})
    assert dark.mean() < 0.01 * base, (dark.mean(), base)
    assert frame_rgb(daemon, s).mean() < 0.01 * base
    # Radiance is linear in emission: double emission, double image (within the noise).
    double = frame_rgb(daemon, s, {"lights": {"ceiling_light": {"emission": [34, 24, 8]}}})
    # var(double - 2 base) = (2 se)^2 + 4 se^2 / 2 = 6 se^2 (base is the mean of two frames)
    assert abs(double.mean() - 2 * base) < 5 * np.sqrt(6) * se + 1e-3, (double.mean(), base, se)
    # Moving the light (its translation) changes the picture well beyond the noise.
    moved = frame_rgb(daemon, s, {"lights": {"ceiling_light": {"emission": [17, 12, 4], "position": [0, -250, 0]}}})
    assert block_diff(a, moved) > 3 * noise, (block_diff(a, moved), noise)
    # A whole transform back to identity restores the original picture.
    back = frame_rgb(daemon, s, {"lights": {"ceiling_light": {"transform": {"translate": [0, 0, 0]}}}})
    assert block_diff(a, back) < 2.5 * noise, (block_diff(a, back), noise)
    assert daemon.req("DELETE", s["href"]).status == 204


def test_camera_changes(daemon):
    s = new_session(daemon, width=32, height=32, seed=6, params={"spp": 4})
    a = frame_rgb(daemon, s)
    b = frame_rgb(daemon, s)
    noise = block_diff(a, b)
    # One camera member alone: the others stay.
    zoom = frame_rgb(daemon, s, {"camera": {"fov_deg": 20}})
    cam = daemon.req("GET", s["href"]).json()["camera"]
    assert cam["fov_deg"] == pytest.approx(20) and cam["position"] == [278, 273, -800]
    assert cam["look_at"] == [278, 273, 0] and cam["up"] == [0, 1, 0]
    assert block_diff(a, zoom) > 3 * noise, (block_diff(a, zoom), noise)
    moved = frame_rgb(daemon, s, {"camera": {"fov_deg": 39.3077, "position": [450, 450, -500]}})
    assert block_diff(a, moved) > 3 * noise, (block_diff(a, moved), noise)
    back = frame_rgb(daemon, s, {"camera": CORNELL_CAMERA})
    assert block_diff(a, back) < 2.5 * noise, (block_diff(a, back), noise)
    assert daemon.req("DELETE", s["href"]).status == 204


def test_get_frames_latest_etag(daemon):
    s = new_session(daemon, width=16, height=16, params={"spp": 1})
    posted = [post_frame(daemon, s) for _ in range(2)]
    for n, p in enumerate(posted):
        r = daemon.req("GET", f"{s['href']}/frames/{n}")
        assert r.status == 200 and r.header("Content-Type") == "image/x-exr", repr(r)
        assert r.header("X-Frame") == str(n)
        assert np.array_equal(exr_rgb(r.body), exr_rgb(p.body))
        etag = r.header("ETag")
        assert etag and not etag.startswith("W/") and re.fullmatch(r'"[^"]+"', etag), repr(r)
        assert r.header("Cache-Control") == "private, max-age=31536000, immutable", repr(r)
        nm = daemon.req("GET", f"{s['href']}/frames/{n}", headers={"If-None-Match": etag})
        assert nm.status == 304 and nm.body == b"", repr(nm)
        other = daemon.req("GET", f"{s['href']}/frames/{n}", headers={"If-None-Match": '"something-else"'})
        assert other.status == 200, repr(other)
    assert daemon.req("GET", f"{s['href']}/frames/0").header("ETag") != daemon.req("GET", f"{s['href']}/frames/1").header("ETag")
    r = daemon.req("GET", f"{s['href']}/frames/latest")
    assert r.status == 303 and r.header("Location") == f"{s['href']}/frames/1", repr(r)
    # The query goes along with the redirect (a preview page asks for latest?exposure=...).
    r = daemon.req("GET", f"{s['href']}/frames/latest?exposure=1.5&tonemap=aces")
    assert r.status == 303 and r.header("Location") == f"{s['href']}/frames/1?exposure=1.5&tonemap=aces", repr(r)
    js = daemon.req("GET", f"{s['href']}/frames/1", headers={"Accept": "application/json"})
    assert js.status == 200 and js.json()["frame"] == 1, repr(js)
    assert_problem(daemon.req("GET", f"{s['href']}/frames/7"), 404, "not-found")
    assert daemon.req("DELETE", s["href"]).status == 204


def test_accumulation(daemon):
    s = new_session(daemon, width=16, height=16, seed=2, params={"spp": 1})
    assert_problem(daemon.req("GET", s["href"] + "/accumulation"), 404, "not-found", where="before the first frame")
    frames = [frame_rgb(daemon, s) for _ in range(3)]
    r = daemon.req("GET", s["href"] + "/accumulation", headers={"Accept": "application/json"})
    assert r.status == 200 and r.json()["frames"] == 3 and r.header("X-Accumulated-Frames") == "3", repr(r)
    r = daemon.req("GET", s["href"] + "/accumulation")
    assert r.status == 200 and r.header("Content-Type") == "image/x-exr", repr(r)
    np.testing.assert_allclose(exr_rgb(r.body), np.mean(frames, axis=0), rtol=1e-5, atol=1e-6)
    r = daemon.req("GET", s["href"] + "/accumulation", headers={"Accept": "image/png"})
    assert r.status == 200 and r.body[:8] == b"\x89PNG\r\n\x1a\n", repr(r)
    # A change starts a new accumulation.
    changed = frame_rgb(daemon, s, {"camera": {"fov_deg": 30}})
    r = daemon.req("GET", s["href"] + "/accumulation")
    np.testing.assert_allclose(exr_rgb(r.body), changed, rtol=1e-5, atol=1e-6)
    assert daemon.req("GET", s["href"] + "/accumulation", headers={"Accept": "application/json"}).json()["frames"] == 1
    assert daemon.req("DELETE", s["href"]).status == 204


def test_frame_eviction(tmp_path_factory):
    d = start_daemon(tmp_path_factory, "evict", "--threads", "2", "--frames-kept", "2")
    try:
        assert d.req("GET", "/v1/limits").json()["frames_kept"] == 2
        s = new_session(d, width=16, height=16)
        assert s["frames_kept"] == 2
        for _ in range(4):
            post_frame(d, s)
        for n in (0, 1):
            assert_problem(d.req("GET", f"{s['href']}/frames/{n}"), 410, "frame-evicted", where=f"frame {n}")
        for n in (2, 3):
            assert d.req("GET", f"{s['href']}/frames/{n}").status == 200
        assert_problem(d.req("GET", f"{s['href']}/frames/4"), 404, "not-found")
    finally:
        rc, _ = d.stop()
    assert rc == 0


@pytest.mark.concurrency
def test_too_many_sessions(tmp_path_factory):
    d = start_daemon(tmp_path_factory, "maxs", "--threads", "1", "--max-sessions", "2")
    try:
        a = new_session(d, width=16, height=16)
        new_session(d, width=16, height=16)
        r = d.req("POST", f"{CORNELL}/sessions", json_body={"width": 16, "height": 16})
        body = assert_problem(r, 429, "too-many-sessions")
        assert re.fullmatch(r"\d+", r.header("Retry-After") or ""), repr(r)
        assert body.get("limit") == 2, repr(r)
        metrics = d.req("GET", "/metrics").body.decode()
        assert metric_value(metrics, "restird_sessions") == 2
        assert d.req("DELETE", a["href"]).status == 204
        new_session(d, width=16, height=16)
    finally:
        rc, _ = d.stop()
    assert rc == 0


def test_references_render_upload_metrics_error_map(daemon, tmp_path):
    s = new_session(daemon, width=32, height=32, seed=4, params={"spp": 2})
    r = daemon.req("POST", s["href"] + "/references/ref32", json_body={"spp": 32})
    assert r.status == 202, repr(r)
    job = r.json()
    assert job["kind"] == "reference" and job["status"] == "queued", job  # as it was queued
    assert job["spp"] == 32 and job["method"] == "pt" and job["href"] == f"{CORNELL}/references/ref32", job
    assert job["progress"]["frames_total"] == 16, job  # 16 passes of spp/16
    loc = r.header("Location")
    assert loc and loc.startswith(s["href"] + "/renders/") and loc.endswith("/" + job["id"]), repr(r)
    job = wait_job(daemon, loc)
    assert job["error"] is None and job["reference"] == "ref32"
    assert job["progress"] == {"frames_done": 16, "frames_total": 16}, job

    r = daemon.req("GET", f"{CORNELL}/references/ref32", headers={"Accept": "application/json"})
    assert r.status == 200, repr(r)
    info = r.json()
    assert (info["name"], info["width"], info["height"], info["spp"], info["method"]) == ("ref32", 32, 32, 32, "pt")
    assert np.allclose(info["mean"], CORNELL_MEAN, rtol=0.15), info
    r = daemon.req("GET", f"{CORNELL}/references/ref32")
    assert r.status == 200 and r.header("Content-Type") == "image/x-exr", repr(r)
    ref = exr_rgb(r.body)
    assert ref.shape == (32, 32, 3) and np.isfinite(ref).all()
    np.testing.assert_allclose(ref.reshape(-1, 3).mean(axis=0), info["mean"], rtol=1e-4)
    r = daemon.req("GET", f"{CORNELL}/references/ref32", headers={"Accept": "image/png"})
    assert r.status == 200 and r.body[:8] == b"\x89PNG\r\n\x1a\n", repr(r)

    # Frame metrics, checked against our own computation from the two EXRs.
    frame = frame_rgb(daemon, s)
    r = daemon.req("GET", s["href"] + "/frames/0/metrics?reference=ref32")
    assert r.status == 200, repr(r)
    m = r.json()
    assert m["reference"] == "ref32" and m["pixels"] == 32 * 32 and m["nonfinite"] == 0
    assert m["rmse"] == pytest.approx(np.sqrt(np.mean((frame - ref) ** 2)), rel=1e-3)
    assert m["mape"] == pytest.approx(np.mean(np.abs(frame - ref) / (ref + 0.01 * ref.mean())), rel=1e-3)
    assert m["relmse"] == pytest.approx(np.mean((frame - ref) ** 2 / (ref ** 2 + 0.01)), rel=1e-3)
    r = post_frame(daemon, s, accept="application/json", query="?reference=ref32")
    assert r.json()["metrics"]["reference"] == "ref32" and r.json()["metrics"]["pixels"] == 1024, repr(r)
    r = daemon.req("GET", s["href"] + "/frames/0/error.png?reference=ref32")
    assert r.status == 200 and r.header("Content-Type") == "image/png" and r.body[:8] == b"\x89PNG\r\n\x1a\n", repr(r)
    # The map's default scale is the 99th percentile (nearest rank) of MAPE's per-pixel terms,
    # the values `restir compare --diff` writes: the reference's mean (about 0.12, not 1) is in
    # the denominator, and r + 0.01 would give a scale far from it.
    def p99(offset):
        e = np.sort((np.abs(frame - ref) / (ref + offset)).mean(axis=2).astype(np.float32).ravel())
        return float(e[int(np.ceil(0.99 * e.size)) - 1])
    mape_scale, fixed_scale = p99(0.01 * ref.mean()), p99(0.01)
    assert abs(mape_scale / fixed_scale - 1) > 0.05, (mape_scale, fixed_scale)
    assert float(r.header("X-Error-Scale")) == pytest.approx(mape_scale, rel=1e-5), (mape_scale, fixed_scale)
    emap, espec = decode_image(r.body, ".png")
    assert (espec.width, espec.height) == (32, 32)
    r = daemon.req("GET", s["href"] + "/frames/0/error.png?reference=ref32&scale=0.5")
    assert r.status == 200 and float(r.header("X-Error-Scale")) == pytest.approx(0.5), repr(r)

    # Uploads: a ZIP-compressed EXR is stored, a PIZ one is refused by the header gate.
    const = np.full((32, 32, 3), 0.25, np.float32)
    const[..., 1] = 0.5
    r = daemon.req("PUT", f"{CORNELL}/references/up32", body=write_exr(tmp_path / "z.exr", const),
                   headers={"Content-Type": "image/x-exr"})
    assert r.status == 201, repr(r)
    info = daemon.req("GET", f"{CORNELL}/references/up32", headers={"Accept": "application/json"}).json()
    assert (info["width"], info["height"], info["spp"], info["method"]) == (32, 32, 0, None)
    assert np.allclose(info["mean"], [0.25, 0.5, 0.25])
    assert np.array_equal(exr_rgb(daemon.req("GET", f"{CORNELL}/references/up32").body), const)
    r = daemon.req("PUT", f"{CORNELL}/references/up-aces", body=write_exr(tmp_path / "n.exr", const, "none"),
                   headers={"Content-Type": "image/aces"})
    assert r.status == 201, repr(r)
    # Replacing a reference: 200, and the new pixels are served.
    r = daemon.req("PUT", f"{CORNELL}/references/up-aces", body=write_exr(tmp_path / "n2.exr", 2 * const, "rle"),
                   headers={"Content-Type": "image/x-exr"})
    assert r.status == 200, repr(r)
    assert np.array_equal(exr_rgb(daemon.req("GET", f"{CORNELL}/references/up-aces").body), 2 * const)
    r = daemon.req("PUT", f"{CORNELL}/references/piz", body=write_exr(tmp_path / "p.exr", const, "piz"),
                   headers={"Content-Type": "image/x-exr"})
    assert_problem(r, 422, "invalid-reference")
    r = daemon.req("PUT", f"{CORNELL}/references/junk", body=b"v/1\x01" + b"\0" * 60, headers={"Content-Type": "image/x-exr"})
    assert_problem(r, 422, "invalid-reference")
    assert_problem(daemon.req("GET", f"{CORNELL}/references/piz"), 404, "not-found")
    # Metrics against the uploaded constant: mape by API.md's definition.
    m = daemon.req("GET", s["href"] + "/frames/0/metrics?reference=up32").json()
    assert m["mape"] == pytest.approx(np.mean(np.abs(frame - const) / (const + 0.01 * const.mean())), rel=1e-3)
    # A NaN in the reference leaves its pixel out, counted in nonfinite as API.md says ("either image").
    holed = const.copy()
    holed[3, 5, 1] = np.nan
    r = daemon.req("PUT", f"{CORNELL}/references/holed", body=write_exr(tmp_path / "h.exr", holed),
                   headers={"Content-Type": "image/x-exr"})
    assert r.status == 201, repr(r)
    m = daemon.req("GET", s["href"] + "/frames/0/metrics?reference=holed").json()
    assert (m["pixels"], m["nonfinite"]) == (32 * 32 - 1, 1), m
    # A reference of another size does not fit the session.
    r = daemon.req("PUT", f"{CORNELL}/references/up16", body=write_exr(tmp_path / "s.exr", const[:16, :16]),
                   headers={"Content-Type": "image/x-exr"})
    assert r.status == 201, repr(r)
    assert_problem(daemon.req("GET", s["href"] + "/frames/0/metrics?reference=up16"), 422, "reference-mismatch")
    assert_problem(daemon.req("GET", s["href"] + "/frames/0/metrics?reference=nope"), 404, "not-found")
    assert_problem(daemon.req("GET", f"{CORNELL}/references/nope"), 404, "not-found")
    assert daemon.req("DELETE", s["href"]).status == 204


def test_sms_reference_finds_the_caustics_pt_misses(daemon, tmp_path):
    """`"method": "sms"` renders a reference with specular manifold sampling for the caustic
    paths: on reflective-plane (a small light seen in a bumpy mirror) two such references with
    independent seeds agree far better than two `pt` ones at the same spp, whose caustic comes
    from rare BSDF-sampled hits of the light. Measured with the CLI at 32x32, 32 spp: RMSE
    between two seeds 0.0036 (sms) against 0.55 (pt). A reference that ignored the method fails."""
    plane = "/v1/scenes/reflective-plane"
    imgs = {}
    for method in ("pt", "sms"):
        for seed in (1, 2):
            s = new_session(daemon, scene="reflective-plane", width=32, height=32, seed=seed, params={"spp": 1})
            name = f"{method}{seed}"
            r = daemon.req("POST", s["href"] + f"/references/{name}", json_body={"spp": 32, "method": method})
            assert r.status == 202 and r.json()["method"] == method, repr(r)
            job = wait_job(daemon, r.header("Location"))
            assert job["error"] is None and job["method"] == method and job["spp"] == 32, job
            info = daemon.req("GET", f"{plane}/references/{name}", headers={"Accept": "application/json"}).json()
            assert info["method"] == method and info["spp"] == 32, info
            imgs[name] = exr_rgb(daemon.req("GET", f"{plane}/references/{name}").body)
            assert np.isfinite(imgs[name]).all()
            assert daemon.req("DELETE", s["href"]).status == 204

    def rmse(a, b):
        return float(np.sqrt(np.mean((imgs[a] - imgs[b]) ** 2)))

    assert rmse("sms1", "sms2") < 0.05 * rmse("pt1", "pt2"), (rmse("sms1", "sms2"), rmse("pt1", "pt2"))
    # And it estimates the same image as the CLI's `sms` (measured: within 1.5 % per channel): the
    # caustic paths carry 58 % of this image's mean (caustics_only at 256 spp: 0.0177 of 0.0302 in
    # red), so a reference that dropped them, or counted them twice alongside pt's, misses by far
    # more than the 10 % allowed.
    cli, _ = render(ROOT / "scenes" / "reflective-plane" / "scene.json", tmp_path / "cli.exr", spp=256, seed=9,
                    extra=["--method", "sms", "--params", json.dumps({"bernoulli_cap": 0})])
    ours = (imgs["sms1"] + imgs["sms2"]).reshape(-1, 3).mean(axis=0) / 2
    np.testing.assert_allclose(ours, cli.reshape(-1, 3).mean(axis=0), rtol=0.1)
    # An unknown method names the field; an uploaded reference has none.
    s = new_session(daemon, scene="reflective-plane", width=8, height=8)
    r = daemon.req("POST", s["href"] + "/references/x", json_body={"method": "bdpt"})
    assert_problem(r, 422, "invalid-field", "/method")
    assert 'unknown reference method "bdpt" (known: pt, sms)' in r.json()["detail"], repr(r)
    assert daemon.req("DELETE", s["href"]).status == 204
    # A scene with more caustic casters than SMS holds (64): a pt session works, an sms reference
    # of it is refused before a job starts.
    scene = cornell_scene()
    scene["materials"]["glass"] = {"type": "dielectric", "ior": 1.5}
    scene["shapes"] += [{"type": "sphere", "material": "glass", "center": [30 + 7 * i, 60, 200], "radius": 3,
                         "caustic_caster": True} for i in range(65)]
    assert daemon.req("PUT", "/v1/scenes/many-casters", json_body=scene).status == 201
    s = new_session(daemon, scene="many-casters", width=8, height=8)
    r = daemon.req("POST", s["href"] + "/references/x", json_body={"method": "sms"})
    assert_problem(r, 422, "limit-exceeded", "/method")
    assert r.json()["detail"] == "more than 64 caustic casters", repr(r)
    r = daemon.req("POST", s["href"] + "/references/x", json_body={"spp": 1})
    assert r.status == 202 and r.json()["method"] == "pt", repr(r)
    wait_job(daemon, r.header("Location"))
    assert daemon.req("DELETE", s["href"]).status == 204
    assert daemon.req("DELETE", "/v1/scenes/many-casters").status == 204


def test_frame_exr_compression_per_request(daemon):
    """?compression= picks the EXR codec (none by default: docs/benchmarks.md measures it the
    fastest to deliver); every codec holds the same pixels, and each is a cache variant of its
    own."""
    s = new_session(daemon, width=24, height=16, params={"spp": 1})
    assert daemon.req("POST", s["href"] + "/frames", headers={"Accept": "application/json"}).status == 200
    seen, etags = {}, set()
    for q in ("", "?compression=none", "?compression=zip", "?compression=piz", "?compression=zip&pixel=half"):
        r = daemon.req("GET", s["href"] + "/frames/0" + q)
        assert r.status == 200 and r.header("Content-Type") == "image/x-exr", repr(r)
        img, spec = decode_image(r.body, ".exr")
        seen[q] = (spec.get_string_attribute("compression"), img)
        etags.add(r.header("ETag"))
    assert {q: c for q, (c, _) in seen.items()} == {"": "none", "?compression=none": "none", "?compression=zip": "zip",
                                                     "?compression=piz": "piz", "?compression=zip&pixel=half": "zip"}
    assert len(etags) == 4  # "" and "?compression=none" are the same representation
    for q in ("?compression=zip", "?compression=piz"):
        assert np.array_equal(seen[q][1], seen[""][1]), q
    assert np.allclose(seen["?compression=zip&pixel=half"][1], seen[""][1], rtol=1e-3, atol=1e-4)
    # The Python client passes it through.
    sys.path.insert(0, str(ROOT / "clients" / "python"))
    import restir
    client = restir.Client(f"http://127.0.0.1:{daemon.port}")
    body = client.get_frame(s["id"], 0, compression="zip", scene="cornell-box")
    assert decode_image(body, ".exr")[1].get_string_attribute("compression") == "zip"
    r = daemon.req("GET", s["href"] + "/frames/0?compression=dwaa")
    assert_problem(r, 400, "bad-query", "?compression")
    assert r.json()["detail"] == "compression must be 'none', 'zip' or 'piz', got 'dwaa'"
    assert_problem(daemon.req("GET", s["href"] + "/frames/0?compression=ZIP"), 400, "bad-query", "?compression")
    assert daemon.req("DELETE", s["href"]).status == 204


def test_metrics_series_gives_both_regimes(daemon, tmp_path):
    """A job's series scores each frame (real time) and the image a user keeping the still view
    would keep (converge): the accumulation for pt, whose frames are independent, and for a
    restir_pt session under the converge profile, whose frames are too; the frame itself for
    restir_pt under the real-time profile, whose correlated frames are never averaged."""
    const = np.full((16, 16, 3), 0.2, np.float32)
    r = daemon.req("PUT", f"{CORNELL}/references/regimes-ref", body=write_exr(tmp_path / "c.exr", const),
                   headers={"Content-Type": "image/x-exr"})
    assert r.status == 201, repr(r)
    nframes = 4
    for method, params, profile in (("pt", {"spp": 1}, "real_time"), ("restir_pt", {}, "real_time"),
                                    ("restir_pt", {}, "converge")):
        s = new_session(daemon, method=method, width=16, height=16, seed=3, params=params, profile=profile)
        averaged = method == "pt" or profile == "converge"
        r = daemon.req("POST", s["href"] + "/renders",
                       json_body={"animation": {"fps": 10, "frames": nframes}, "reference": "regimes-ref"})
        assert r.status == 202, repr(r)
        loc = r.header("Location")
        job = wait_job(daemon, loc)
        imgs = [exr_rgb(daemon.req("GET", href).body) for href in job["frames"]]
        series = daemon.req("GET", loc + "/metrics").json()["series"]
        for i, row in enumerate(series):
            conv = row["converge"]
            if averaged:
                want = np.mean(imgs[:i + 1], axis=0)
                assert conv["image"] == "accumulation" and conv["frames"] == i + 1, row
            else:
                want = imgs[i]
                assert conv["image"] == "frame" and conv["frames"] == 0, row
                assert conv["rmse"] == row["rmse"] and conv["mape"] == row["mape"], row
            assert conv["rmse"] == pytest.approx(np.sqrt(np.mean((want - const) ** 2)), rel=1e-4), (method, i)
            want_relmse = np.mean((want - const) ** 2 / (const ** 2 + 0.01))
            assert conv["relmse"] == pytest.approx(want_relmse, rel=1e-3), (method, i)
        lines = daemon.req("GET", loc + "/metrics", headers={"Accept": "text/csv"}).body.decode().strip().splitlines()
        assert lines[0].split(",")[6:] == ["converge_image", "converge_frames", "converge_mape", "converge_rmse",
                                           "converge_relmse"]
        assert float(lines[-1].split(",")[9]) == pytest.approx(series[-1]["converge"]["rmse"], rel=1e-6)
        # Scored against another reference later, only the kept frames can be: no converge figure.
        other = daemon.req("GET", loc + "/metrics?reference=regimes-ref").json()["series"]
        assert [row["converge"] for row in other] == [None] * nframes
        assert daemon.req("DELETE", s["href"]).status == 204


@pytest.mark.concurrency
def test_animation_job_idempotency_metrics(daemon, tmp_path):
    s = new_session(daemon, width=16, height=16, seed=8, params={"spp": 1})
    const = np.full((16, 16, 3), 0.2, np.float32)
    for name in ("anim-ref", "anim-ref2"):
        r = daemon.req("PUT", f"{CORNELL}/references/{name}", body=write_exr(tmp_path / f"{name}.exr", const),
                       headers={"Content-Type": "image/x-exr"})
        assert r.status == 201, repr(r)
    fps, nframes = 10, 5
    anim = {"animation": {"fps": fps, "frames": nframes, "interpolation": "linear",
                          "camera_keys": [{"t": 0, "position": [278, 273, -800], "look_at": [278, 273, 0]},
                                          {"t": 0.4, "position": [300, 273, -780]}],
                          "light_keys": {"ceiling_light": [{"t": 0, "emission": [17, 12, 4]},
                                                           {"t": 0.4, "emission": [0, 0, 0]}]}},
            "reference": "anim-ref"}
    key = {"Idempotency-Key": f"anim-{os.getpid()}-{time.monotonic_ns()}"}
    r = daemon.req("POST", s["href"] + "/renders", json_body=anim, headers=key)
    assert r.status == 202, repr(r)
    job = r.json()
    assert job["kind"] == "animation" and job["progress"]["frames_total"] == nframes
    loc = r.header("Location")
    assert loc == f"{s['href']}/renders/{job['id']}", repr(r)
    again = daemon.req("POST", s["href"] + "/renders", json_body=anim, headers=key)
    assert again.status in (200, 202) and again.json()["id"] == job["id"], repr(again)
    assert again.header("Location") == loc
    job = wait_job(daemon, loc)
    assert job["error"] is None and job["reference"] == "anim-ref"
    assert job["progress"] == {"frames_done": nframes, "frames_total": nframes}
    assert len(job["frames"]) == nframes
    imgs = []
    for href in job["frames"]:
        r = daemon.req("GET", href)
        assert r.status == 200 and r.header("Content-Type") == "image/x-exr", repr(r)
        imgs.append(exr_rgb(r.body))
    assert imgs[0].mean() > 0.05 and imgs[-1].mean() < 0.01 * imgs[0].mean()  # the light fades out
    # Per-frame series as JSON (a list of rows) and as CSV.
    r = daemon.req("GET", loc + "/metrics")
    assert r.status == 200 and r.header("Content-Type").startswith("application/json"), repr(r)
    body = r.json()
    assert body["reference"] == "anim-ref", body
    series = body["series"]
    assert [row["frame"] for row in series] == list(range(nframes))
    for i, row in enumerate(series):
        assert set(row) >= {"frame", "time_s", "render_ms", "mape", "rmse", "relmse"}
        assert row["time_s"] == pytest.approx(i / fps) and row["render_ms"] > 0
        assert row["rmse"] == pytest.approx(np.sqrt(np.mean((imgs[i] - const) ** 2)), rel=1e-3)
    r = daemon.req("GET", loc + "/metrics", headers={"Accept": "text/csv"})
    assert r.status == 200 and r.header("Content-Type").startswith("text/csv"), repr(r)
    lines = r.body.decode().strip().splitlines()
    assert lines[0].startswith("frame,time_s,render_ms,mape,rmse,relmse,") and len(lines) == nframes + 1
    assert [int(x.split(",")[0]) for x in lines[1:]] == list(range(nframes))
    assert float(lines[-1].split(",")[4]) == pytest.approx(series[-1]["rmse"], rel=1e-4)
    r = daemon.req("GET", loc + "/metrics?reference=anim-ref2")
    assert r.status == 200 and r.json()["reference"] == "anim-ref2", repr(r)
    assert [row["frame"] for row in r.json()["series"]] == list(range(nframes))
    for i, row in enumerate(r.json()["series"]):  # same constant, so the same metrics
        assert row["rmse"] == pytest.approx(series[i]["rmse"], rel=1e-6)
    # Without a reference the metric cells are null (JSON) or empty (CSV).
    r = daemon.req("POST", s["href"] + "/renders", json_body={"animation": {"fps": 10, "frames": 2}})
    assert r.status == 202, repr(r)
    plain = wait_job(daemon, r.header("Location"))
    assert plain["reference"] is None and plain["id"] != job["id"]
    body = daemon.req("GET", r.header("Location") + "/metrics").json()
    assert body["reference"] is None and [row["mape"] for row in body["series"]] == [None, None]
    csv = daemon.req("GET", r.header("Location") + "/metrics", headers={"Accept": "text/csv"}).body.decode()
    assert [line.split(",")[3:] for line in csv.strip().splitlines()[1:]] == [[""] * 8] * 2, csv
    assert daemon.req("DELETE", s["href"]).status == 204


@pytest.mark.concurrency
def test_cancel_running_job(daemon):
    s = new_session(daemon, width=32, height=32, params={"spp": 1})
    r = daemon.req("POST", s["href"] + "/renders", json_body={"animation": {"fps": 30, "frames": 5000}})
    assert r.status == 202, repr(r)
    loc = r.header("Location")
    deadline = time.monotonic() + 30
    while True:
        job = daemon.req("GET", loc).json()
        if job["status"] == "running" and job["progress"]["frames_done"] >= 1:
            break
        assert job["status"] in ("queued", "running") and time.monotonic() < deadline, job
        time.sleep(0.02)
    r = daemon.req("DELETE", loc)
    assert r.status == 202, repr(r)
    job = wait_job(daemon, loc, done=("cancelled", "done", "failed"), timeout=30)
    assert job["status"] == "cancelled", job
    done = job["progress"]["frames_done"]
    # The session keeps its last 16 frames: the job offers those and counts the rest evicted.
    assert done < 5000 and len(job["frames"]) == min(done, 16) and job["frames_evicted"] == done - len(job["frames"])
    assert daemon.req("GET", s["href"]).json()["busy"] is False
    # Deleting a session cancels its running job first.
    r = daemon.req("POST", s["href"] + "/renders", json_body={"animation": {"fps": 30, "frames": 5000}})
    assert r.status == 202, repr(r)
    wait_job(daemon, r.header("Location"), done=("running",))
    t0 = time.monotonic()
    assert daemon.req("DELETE", s["href"]).status == 204
    assert time.monotonic() - t0 < 10
    assert_problem(daemon.req("GET", r.header("Location")), 404, "not-found")
    assert_problem(daemon.req("GET", s["href"]), 404, "not-found")


@pytest.mark.concurrency
def test_events_stream(daemon):
    s = new_session(daemon, width=16, height=16, params={"spp": 1})
    conn = http.client.HTTPConnection("127.0.0.1", daemon.port, timeout=20)
    conn.request("GET", s["href"] + "/events", headers={"Accept": "text/event-stream"})
    resp = conn.getresponse()
    assert resp.status == 200 and resp.headers["Content-Type"].startswith("text/event-stream")
    events, text, lock, ended = [], [""], threading.Lock(), threading.Event()

    def reader():
        try:
            while True:
                chunk = resp.read1(4096)
                if not chunk:
                    break
                with lock:
                    text[0] += chunk.decode()
                    while "\n\n" in text[0]:
                        block, text[0] = text[0].split("\n\n", 1)
                        fields = {}
                        for line in block.splitlines():
                            if line.startswith(":") or ":" not in line:
                                continue
                            k, v = line.split(":", 1)
                            fields[k] = v[1:] if v.startswith(" ") else v
                        if "event" in fields:
                            events.append((fields["event"], json.loads(fields.get("data", "null"))))
        except (OSError, http.client.HTTPException):
            pass
        finally:
            ended.set()

    t = threading.Thread(target=reader, daemon=True)
    t.start()

    def wait_for(pred, what, timeout=20):
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            with lock:
                hit = [e for e in events if pred(e)]
            if hit:
                return hit[0]
            time.sleep(0.02)
        raise AssertionError(f"no {what} event within {timeout} s; got {events}")

    try:
        time.sleep(0.2)
        post_frame(daemon, s)
        ev = wait_for(lambda e: e[0] == "frame", "frame")
        assert ev[1]["frame"] == 0 and ev[1]["href"] == s["href"] + "/frames/0", ev
        r = daemon.req("POST", s["href"] + "/renders", json_body={"animation": {"fps": 10, "frames": 2}})
        assert r.status == 202, repr(r)
        rid = r.json()["id"]
        done = wait_for(lambda e: e[0] == "done", "done")
        assert done[1] == {"job": rid, "status": "done"} or (done[1]["job"] == rid and done[1]["status"] == "done"), done
        with lock:
            assert any(e[0] == "frame" and e[1].get("job") == rid for e in events), events
            assert any(e[0] == "progress" and e[1]["job"] == rid and e[1]["frames_total"] == 2 for e in events), events
        # Deleting the session ends the stream.
        assert daemon.req("DELETE", s["href"]).status == 204
        assert ended.wait(10), "the event stream did not end when the session was deleted"
    finally:
        conn.close()


# ---- 2. determinism ----

def test_same_seed_same_requests_bit_identical(daemon):
    steps = [None, {"camera": {"position": [250, 280, -760], "fov_deg": 35}},
             {"lights": {"ceiling_light": {"emission": [10, 10, 10]}}},
             {"lights": {"ceiling_light": {"position": [20, -30, 0]}}}, {"time_s": 0.25}]

    def run(seed):
        s = new_session(daemon, width=24, height=24, seed=seed, params={"spp": 2})
        out = [frame_rgb(daemon, s, step) for step in steps]
        assert daemon.req("DELETE", s["href"]).status == 204
        return out

    a, b, c = run(11), run(11), run(12)
    for i, (x, y) in enumerate(zip(a, b)):
        assert x.dtype == y.dtype and np.array_equal(x, y), f"step {i}: max diff {np.abs(x - y).max()}"
    assert not np.array_equal(a[0], c[0]), "a different seed gave the same image"


# ---- 3. malformed and hostile requests ----

SC = CORNELL
S = "{S}"  # the table session's href, filled in at run time
SCENE_BYTES = json.dumps(cornell_scene()).encode()
BAD_PLY = b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nend_header\n1\n2\n"
MISSING_CAMERA = json.dumps({"materials": {}, "shapes": []}).encode()
UNKNOWN_MATERIAL = json.dumps(dict(cornell_scene(), shapes=[dict(cornell_scene()["shapes"][0], material="nope")])).encode()
MISSING_ASSET = json.dumps(mesh_scene("missing.ply")).encode()
ANIM_BAD_KEYS = json.dumps({"animation": {"fps": 30, "frames": 2, "camera_keys": [
    {"t": 1, "position": [0, 0, -800]}, {"t": 0.5, "position": [1, 0, -800]}]}}).encode()
PNG = {"Accept": "image/png"}
CHUNKED = "chunked"

# (name, method, path, headers, body, status, problem type suffix, field or None)
CASES = [
    # not JSON at all
    ("not-json", "POST", f"{SC}/sessions", J, b"hello", 400, "malformed-json", None),
    ("unterminated-object", "POST", f"{SC}/sessions", J, b'{"width": 16', 400, "malformed-json", None),
    ("trailing-garbage", "POST", f"{SC}/sessions", J, b'{"width": 16} x', 400, "malformed-json", None),
    ("two-documents", "POST", f"{SC}/sessions", J, b"{}{}", 400, "malformed-json", None),
    ("trailing-comma", "POST", f"{SC}/sessions", J, b'{"width": 16,}', 400, "malformed-json", None),
    ("single-quotes", "POST", f"{SC}/sessions", J, b"{'width': 16}", 400, "malformed-json", None),
    ("nan-token", "POST", f"{SC}/sessions", J, b'{"width": NaN}', 400, "malformed-json", None),
    ("infinity-token", "POST", f"{SC}/sessions", J, b'{"seed": Infinity}', 400, "malformed-json", None),
    ("minus-infinity-token", "POST", f"{S}/frames", J, b'{"camera": {"fov_deg": -Infinity}}', 400, "malformed-json", None),
    ("nesting-10000", "POST", f"{SC}/sessions", J, b"[" * 10000, 400, "malformed-json", None),
    ("nesting-21-balanced", "POST", f"{SC}/sessions", J, b'{"params": ' + b"[" * 20 + b"]" * 20 + b"}", 400, "malformed-json", None),
    # valid JSON, wrong shape or meaning
    ("top-level-array", "POST", f"{SC}/sessions", J, b"[]", 422, "invalid-field", ""),
    ("top-level-number", "POST", f"{SC}/sessions", J, b"42", 422, "invalid-field", ""),
    ("width-string", "POST", f"{SC}/sessions", J, b'{"width": "16"}', 422, "invalid-field", "/width"),
    ("width-bool", "POST", f"{SC}/sessions", J, b'{"width": true}', 422, "invalid-field", "/width"),
    ("seed-array", "POST", f"{SC}/sessions", J, b'{"seed": [1]}', 422, "invalid-field", "/seed"),
    ("width-1e999", "POST", f"{SC}/sessions", J, b'{"width": 1e999}', 422, "invalid-field", "/width"),
    ("fov-1e999", "POST", f"{S}/frames", J, b'{"camera": {"fov_deg": 1e999}}', 422, "invalid-field", "/camera/fov_deg"),
    ("width-over-max-side", "POST", f"{SC}/sessions", J, b'{"width": 100000}', 422, "limit-exceeded", "/width"),
    ("width-2^40", "POST", f"{SC}/sessions", J, b'{"width": 1099511627776}', 422, "limit-exceeded", "/width"),
    ("width-negative", "POST", f"{SC}/sessions", J, b'{"width": -16}', 422, "invalid-field", "/width"),
    ("height-zero", "POST", f"{SC}/sessions", J, b'{"height": 0}', 422, "invalid-field", "/height"),
    ("width-non-integral", "POST", f"{SC}/sessions", J, b'{"width": 16.5}', 422, "invalid-field", "/width"),
    ("spp-over-max-spp", "POST", f"{SC}/sessions", J, b'{"params": {"spp": 1000000}}', 422, "limit-exceeded", "/params/spp"),
    ("spp-zero", "POST", f"{SC}/sessions", J, b'{"params": {"spp": 0}}', 422, "invalid-field", "/params/spp"),
    ("unknown-top-level-key", "POST", f"{SC}/sessions", J, b'{"colour": 1}', 422, "invalid-field", "/colour"),
    ("unknown-params-key", "POST", f"{SC}/sessions", J, b'{"params": {"sppp": 4}}', 422, "invalid-field", "/params/sppp"),
    ("duplicate-key", "POST", f"{SC}/sessions", J, b'{"width": 16, "width": 32}', 422, "invalid-field", "/width"),
    ("duplicate-nested-key", "POST", f"{SC}/sessions", J, b'{"params": {"spp": 1, "spp": 2}}', 422, "invalid-field", "/params/spp"),
    ("unknown-method", "POST", f"{SC}/sessions", J, b'{"method": "magic"}', 422, "invalid-field", "/method"),
    ("params-array", "POST", f"{SC}/sessions", J, b'{"params": []}', 422, "invalid-field", "/params"),
    ("unknown-profile", "POST", f"{SC}/sessions", J, b'{"method": "restir_pt", "profile": "fast"}', 422, "invalid-field", "/profile"),
    ("camera-2-vector", "POST", f"{S}/frames", J, b'{"camera": {"position": [1, 2]}}', 422, "invalid-field", "/camera/position"),
    ("camera-fov-zero", "POST", f"{S}/frames", J, b'{"camera": {"fov_deg": 0}}', 422, "invalid-field", "/camera/fov_deg"),
    ("camera-unknown-key", "POST", f"{S}/frames", J, b'{"camera": {"zoom": 2}}', 422, "invalid-field", "/camera/zoom"),
    ("unknown-light", "POST", f"{S}/frames", J, b'{"lights": {"nope": {"emission": [0, 0, 0]}}}', 422, "invalid-field", "/lights/nope"),
    ("light-unknown-key", "POST", f"{S}/frames", J, b'{"lights": {"ceiling_light": {"colour": [1, 1, 1]}}}', 422, "invalid-field", "/lights/ceiling_light/colour"),
    ("light-negative-emission", "POST", f"{S}/frames", J, b'{"lights": {"ceiling_light": {"emission": [-1, 0, 0]}}}', 422, "invalid-field", None),
    ("time-string", "POST", f"{S}/frames", J, b'{"time_s": "0.5"}', 422, "invalid-field", "/time_s"),
    ("render-missing-animation", "POST", f"{S}/renders", J, b"{}", 422, "invalid-field", "/animation"),
    ("render-fps-zero", "POST", f"{S}/renders", J, b'{"animation": {"fps": 0, "frames": 2}}', 422, "invalid-field", "/animation/fps"),
    ("render-frames-over-limit", "POST", f"{S}/renders", J, b'{"animation": {"fps": 30, "frames": 10001}}', 422, "limit-exceeded", "/animation/frames"),
    ("render-keys-not-increasing", "POST", f"{S}/renders", J, ANIM_BAD_KEYS, 422, "invalid-field", "/animation/camera_keys/1/t"),
    ("render-bad-interpolation", "POST", f"{S}/renders", J, b'{"animation": {"fps": 30, "frames": 2, "interpolation": "cubic"}}', 422, "invalid-field", "/animation/interpolation"),
    ("render-unknown-reference", "POST", f"{S}/renders", J, b'{"animation": {"fps": 30, "frames": 2}, "reference": "nope"}', 422, "invalid-field", "/reference"),
    ("reference-spp-negative", "POST", f"{S}/references/r-neg", J, b'{"spp": -1}', 422, "invalid-field", "/spp"),
    ("reference-spp-over-limit", "POST", f"{S}/references/r-big", J, b'{"spp": 1000000}', 422, "limit-exceeded", "/spp"),
    # scenes and assets
    ("scene-missing-camera", "PUT", "/v1/scenes/tbl-bad", J, MISSING_CAMERA, 422, "invalid-scene", "/camera"),
    ("scene-unknown-material", "PUT", "/v1/scenes/tbl-bad", J, UNKNOWN_MATERIAL, 422, "invalid-scene", "/shapes/0/material"),
    ("scene-missing-asset", "PUT", "/v1/scenes/tbl-bad", J, MISSING_ASSET, 422, "invalid-scene", "/shapes/0/file"),
    ("put-builtin-scene", "PUT", SC, J, SCENE_BYTES, 409, "conflict", None),
    ("asset-to-builtin-scene", "PUT", f"{SC}/assets/m.ply", {"Content-Type": "model/ply"}, TETRA_PLY, 409, "conflict", None),
    ("asset-undecodable", "PUT", "/v1/scenes/tbl-assets/assets/bad.ply", {"Content-Type": "model/ply"}, BAD_PLY, 422, "invalid-asset", None),
    ("asset-wrong-content-type", "PUT", "/v1/scenes/tbl-assets/assets/m.ply", {"Content-Type": "image/png"}, TETRA_PLY, 415, "unsupported-media-type", None),
    # ids and names in paths
    ("session-id-too-long", "GET", f"{SC}/sessions/{'s' * 65}", {}, None, 400, "bad-id", None),
    ("session-id-bad-chars", "GET", f"{SC}/sessions/s%21x", {}, None, 400, "bad-id", None),
    ("scene-id-too-long", "PUT", f"/v1/scenes/{'a' * 65}", J, SCENE_BYTES, 400, "bad-id", None),
    ("scene-id-bad-chars", "GET", "/v1/scenes/a%20b", {}, None, 400, "bad-id", None),
    ("reference-name-bad-chars", "GET", f"{SC}/references/a.b", {}, None, 400, "bad-id", None),
    ("frame-number-not-a-number", "GET", f"{S}/frames/abc", {}, None, 400, "bad-id", None),
    ("asset-path-traversal", "PUT", "/v1/scenes/tbl-assets/assets/..%2F..%2Fetc%2Fpasswd.ply", {"Content-Type": "model/ply"}, TETRA_PLY, 400, "bad-id", None),
    ("asset-dotdot", "PUT", "/v1/scenes/tbl-assets/assets/..", {"Content-Type": "model/ply"}, TETRA_PLY, 400, "bad-id", None),
    ("asset-hidden", "PUT", "/v1/scenes/tbl-assets/assets/.hidden.ply", {"Content-Type": "model/ply"}, TETRA_PLY, 400, "bad-id", None),
    ("asset-bad-extension", "PUT", "/v1/scenes/tbl-assets/assets/x.txt", {"Content-Type": "text/plain"}, TETRA_PLY, 400, "bad-id", None),
    ("idempotency-key-bad", "POST", f"{S}/renders", dict(J, **{"Idempotency-Key": "no spaces!"}), b'{"animation": {"fps": 30, "frames": 1}}', 400, "bad-header", "Idempotency-Key"),
    # framing, sizes and media types
    ("json-over-limit-sent", "POST", f"{SC}/sessions", J, b'{"seed": 1' + b" " * MAX_JSON_BODY + b"}", 413, "body-too-large", None),
    ("json-over-limit-expect-100", "POST", f"{SC}/sessions", dict(J, **{"Content-Length": "1000000", "Expect": "100-continue"}), None, 413, "body-too-large", None),
    ("json-over-64MiB-not-sent", "POST", f"{SC}/sessions", dict(J, **{"Content-Length": "100000000"}), None, 413, "body-too-large", None),
    ("asset-over-limit-expect-100", "PUT", "/v1/scenes/tbl-assets/assets/big.ply", {"Content-Type": "model/ply", "Content-Length": "2000000", "Expect": "100-continue"}, None, 413, "body-too-large", None),
    ("chunked-scene-put", "PUT", "/v1/scenes/tbl-chunked", dict(J, **{CHUNKED: 1}), SCENE_BYTES, 411, "length-required", None),
    ("chunked-session-post", "POST", f"{SC}/sessions", dict(J, **{CHUNKED: 1}), b"{}", 411, "length-required", None),
    ("text-plain-json", "POST", f"{SC}/sessions", {"Content-Type": "text/plain"}, b"{}", 415, "unsupported-media-type", None),
    ("no-content-type", "POST", f"{SC}/sessions", {}, b'{"width": 16}', 415, "unsupported-media-type", None),
    ("json-as-reference", "PUT", f"{SC}/references/j", J, b"{}", 415, "unsupported-media-type", None),
    # routes, methods, negotiation, queries
    ("unknown-route", "GET", "/v1/nope", {}, None, 404, "not-found", None),
    ("unknown-version", "GET", "/v2/scenes", {}, None, 404, "not-found", None),
    ("unknown-subresource", "GET", f"{S}/bogus", {}, None, 404, "not-found", None),
    ("delete-healthz", "DELETE", "/healthz", {}, None, 405, "method-not-allowed", None),
    ("put-sessions", "PUT", f"{SC}/sessions", J, b"{}", 405, "method-not-allowed", None),
    ("patch-session", "PATCH", S, J, b"{}", 405, "method-not-allowed", None),
    ("post-frame-n", "POST", f"{S}/frames/0", J, b"{}", 405, "method-not-allowed", None),
    ("accept-html-frame", "GET", f"{S}/frames/0", {"Accept": "text/html"}, None, 406, "not-acceptable", None),
    ("accept-png-scenes", "GET", "/v1/scenes", PNG, None, 406, "not-acceptable", None),
    ("accept-csv-reference", "GET", f"{SC}/references/ref16", {"Accept": "text/csv"}, None, 406, "not-acceptable", None),
    ("exposure-abc", "GET", f"{S}/frames/0?exposure=abc", PNG, None, 400, "bad-query", "?exposure"),
    ("pixel-int", "GET", f"{S}/frames/0?pixel=int", {}, None, 400, "bad-query", "?pixel"),
    ("tonemap-unknown", "GET", f"{S}/frames/0?tonemap=filmic", PNG, None, 400, "bad-query", "?tonemap"),
    ("metrics-without-reference", "GET", f"{S}/frames/0/metrics", {}, None, 400, "bad-query", "?reference"),
    ("error-map-negative-scale", "GET", f"{S}/frames/0/error.png?reference=ref16&scale=-1", {}, None, 400, "bad-query", "?scale"),
    # things that do not exist, or do not fit
    ("frame-not-rendered", "GET", f"{S}/frames/999", {}, None, 404, "not-found", None),
    ("unknown-session", "GET", f"{SC}/sessions/nosuch", {}, None, 404, "not-found", None),
    ("unknown-scene", "GET", "/v1/scenes/tbl-nosuch/sessions", {}, None, 404, "scene-not-loaded", None),
    ("unknown-job", "GET", f"{S}/renders/nosuch", {}, None, 404, "not-found", None),
    ("unknown-job-delete", "DELETE", f"{S}/renders/nosuch", {}, None, 404, "not-found", None),
    # an unknown job is a 404 whatever the Accept header asks for
    ("unknown-job-metrics", "GET", f"{S}/renders/nosuch/metrics", {"Accept": "text/html"}, None, 404, "not-found", None),
    ("unknown-reference", "GET", f"{SC}/references/nope", {}, None, 404, "not-found", None),
    ("metrics-unknown-reference", "GET", f"{S}/frames/0/metrics?reference=nope", {}, None, 404, "not-found", None),
    ("metrics-reference-mismatch", "GET", f"{S}/frames/0/metrics?reference=ref8", {}, None, 422, "reference-mismatch", None),
    ("error-map-reference-mismatch", "GET", f"{S}/frames/0/error.png?reference=ref8", {}, None, 422, "reference-mismatch", None),
]


@pytest.fixture(scope="module")
def table_ctx(daemon, tmp_path_factory):
    """A 16x16 session with frame 0 rendered, and uploaded references ref16 (fits) and ref8 (does not)."""
    s = new_session(daemon, width=16, height=16, params={"spp": 1})
    post_frame(daemon, s)
    tmp = tmp_path_factory.mktemp("refs")
    for name, side in (("ref16", 16), ("ref8", 8)):
        r = daemon.req("PUT", f"{CORNELL}/references/{name}", body=write_exr(tmp / f"{name}.exr", np.full((side, side, 3), 0.3)),
                       headers={"Content-Type": "image/x-exr"})
        assert r.status == 201, repr(r)
    return {"S": s["href"]}


@pytest.mark.parametrize("name,method,path,headers,body,status,slug,field", CASES, ids=[c[0] for c in CASES])
def test_malformed_request(daemon, table_ctx, name, method, path, headers, body, status, slug, field):
    path = path.replace("{S}", table_ctx["S"])
    headers = dict(headers)
    chunked = bool(headers.pop(CHUNKED, None))
    length = headers.pop("Content-Length", "auto")
    r = daemon.raw(method, path, headers, body or b"", chunked=chunked, content_length=length)
    where = f"{name}: {method} {path} {headers} body={(body or b'')[:80]!r}"
    problem = assert_problem(r, status, slug, field, where=where)
    if status == 405:
        allow = {m.strip() for m in (r.header("Allow") or "").split(",") if m.strip()}
        assert allow and method not in allow, f"{where}\n{r!r}"
    if status == 413:
        want = MAX_ASSET_BODY if "assets" in path else MAX_JSON_BODY
        assert problem.get("limit") == want, f"{where}\n{r!r}"
    if slug == "limit-exceeded":
        assert isinstance(problem.get("limit"), int), f"{where}\n{r!r}"
    assert daemon.alive(), f"{where}: the daemon died\n{daemon.stderr()[-3000:]}"


@pytest.mark.parametrize("value", ["-1", "12abc"])
def test_malformed_content_length_refused_by_http_layer(daemon, value):
    """A Content-Length that is not a number never reaches our code: libmicrohttpd answers 400
    itself (an HTML page, and version 0.9.75 repeats its status line), then closes the connection.
    protocol/API.md documents this as the one 4xx that is not problem+json. What we can
    guarantee is the status, the closed connection and a daemon that keeps serving."""
    r = daemon.raw("POST", f"{SC}/sessions", dict(J), b"", content_length=value)
    assert r.status == 400, repr(r)
    assert daemon.alive()
    assert daemon.req("GET", "/healthz").status == 200


def test_table_left_daemon_healthy(daemon, table_ctx, tmp_path):
    r = daemon.req("GET", "/healthz")
    assert r.status == 200 and r.json() == {"status": "ok"}
    # Nothing was written outside the data directory by the traversal attempts, and no scene or
    # asset of the table exists.
    for root, _, files in os.walk(daemon.data_dir):
        for f in files:
            assert "passwd" not in f and not f.startswith("."), os.path.join(root, f)
    ids = [s["id"] for s in daemon.req("GET", "/v1/scenes").json()["scenes"]]
    assert not any(i.startswith("tbl-") for i in ids), ids
    # The table's session still renders.
    r = daemon.req("POST", table_ctx["S"] + "/frames", headers={"Accept": "application/json"})
    assert r.status == 200, repr(r)


@pytest.mark.concurrency
def test_truncated_bodies_do_not_hurt(daemon):
    before = len(daemon.req("GET", f"{CORNELL}/sessions").json()["sessions"])
    head = (f"POST {CORNELL}/sessions HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\n"
            "Content-Length: 1000\r\n\r\n").encode()
    # 1: announce 1000 bytes, send 12, close.
    sock = socket.create_connection(("127.0.0.1", daemon.port), timeout=5)
    sock.sendall(head + b'{"width": 16')
    sock.close()
    # 2: the same, but half-close and wait for whatever the daemon does (an answer or a close).
    sock = socket.create_connection(("127.0.0.1", daemon.port), timeout=5)
    sock.sendall(head + b'{"width": 16')
    sock.shutdown(socket.SHUT_WR)
    try:
        while sock.recv(4096):
            pass
    except OSError:
        pass
    sock.close()
    # 3: headers cut in the middle.
    sock = socket.create_connection(("127.0.0.1", daemon.port), timeout=5)
    sock.sendall(b"POST /v1/scenes/cornell-box/sess")
    sock.close()
    time.sleep(0.2)
    assert daemon.alive(), daemon.stderr()[-3000:]
    assert daemon.req("GET", "/healthz").status == 200
    assert len(daemon.req("GET", f"{CORNELL}/sessions").json()["sessions"]) == before


@pytest.mark.concurrency
def test_second_frame_while_rendering_conflicts(daemon):
    s = new_session(daemon, width=128, height=128, params={"spp": 64})
    slow = {}
    t = threading.Thread(target=lambda: slow.update(r=post_frame(daemon, s, accept="application/json", expect=None)))
    t.start()
    try:
        wait_busy(daemon, s, t)
        assert_problem(post_frame(daemon, s, expect=None), 409, "conflict", where="second frame")
        assert_problem(daemon.req("POST", s["href"] + "/reset"), 409, "conflict", where="reset while rendering")
        assert_problem(daemon.req("GET", s["href"] + "/accumulation"), 409, "conflict", where="accumulation while rendering")
        assert t.is_alive(), "the slow frame ended before the conflicts were checked; raise its spp"
    finally:
        t.join(120)
    assert slow["r"].status == 200 and slow["r"].json()["frame"] == 0, repr(slow["r"])
    assert daemon.req("GET", s["href"]).json()["frames_rendered"] == 1
    assert daemon.req("DELETE", s["href"]).status == 204


# ---- 4. health stays fast while a frame renders ----

HEALTH_SPP = 64  # 256x256x64: seconds on two cores, long enough to span 50 health requests


@pytest.mark.concurrency
def test_healthz_fast_during_render(daemon, record_property):
    s = new_session(daemon, width=256, height=256, params={"spp": HEALTH_SPP})
    slow = {}
    t = threading.Thread(target=lambda: slow.update(r=post_frame(daemon, s, accept="application/json", expect=None)))
    t.start()
    lat = []
    try:
        wait_busy(daemon, s, t)
        for _ in range(50):
            t0 = time.perf_counter()
            r = daemon.req("GET", "/healthz", timeout=10)
            lat.append(time.perf_counter() - t0)
            assert r.status == 200
        rendering = t.is_alive()
    finally:
        t.join(300)
    p50, p99 = np.percentile(lat, 50), np.percentile(lat, 99)
    print(f"\n/healthz during a 256x256 {HEALTH_SPP}-spp frame: p50 {1000 * p50:.2f} ms, "
          f"p99 {1000 * p99:.2f} ms, max {1000 * max(lat):.2f} ms (n={len(lat)})")
    record_property("healthz_p50_ms", round(1000 * p50, 3))
    record_property("healthz_p99_ms", round(1000 * p99, 3))
    assert rendering, "the frame finished before the 50 health requests did; raise HEALTH_SPP"
    assert slow["r"].status == 200, repr(slow["r"])
    assert p99 < 0.5, lat
    assert daemon.req("DELETE", s["href"]).status == 204


# ---- 5. persistence across restarts ----

def test_scenes_survive_restart_and_corrupt_scene_is_skipped(tmp_path):
    data = tmp_path / "data"
    d = Daemon(data, "--threads", "2")
    try:
        r1 = put_mesh_scene(d, "keep-mesh")
        r2 = d.req("PUT", "/v1/scenes/keep-box", json_body=cornell_scene(emission=[8, 8, 8]))
        assert r1.status == 201 and r2.status == 201, (r1, r2)
        hashes = {"keep-mesh": r1.json()["hash"], "keep-box": r2.json()["hash"]}
    finally:
        rc, _ = d.stop()
    assert rc == 0 and "stopped" in d.stderr(), d.stderr()[-2000:]

    d = Daemon(data, "--threads", "2")
    try:
        for sid, h in hashes.items():
            r = d.req("GET", f"/v1/scenes/{sid}")
            assert r.status == 200 and r.json()["hash"] == h and r.json()["builtin"] is False, repr(r)
        assert d.req("GET", "/v1/scenes/keep-mesh").json()["triangles"] == 4
        s = new_session(d, "keep-mesh", width=16, height=16)
        img = frame_rgb(d, s)
        assert img.shape == (16, 16, 3) and img.min() < 0.75  # the mesh is there
    finally:
        rc, _ = d.stop()
    assert rc == 0

    persisted = [p for p in data.rglob("scene.json") if "keep-box" in p.parts]
    assert len(persisted) == 1, sorted(str(p) for p in data.rglob("*"))
    persisted[0].write_bytes(b'{"camera": {"position": [0, 0, ')
    d = Daemon(data, "--threads", "2")
    try:
        assert_problem(d.req("GET", "/v1/scenes/keep-box"), 404, "scene-not-loaded")
        r = d.req("GET", "/v1/scenes/keep-mesh")
        assert r.status == 200 and r.json()["hash"] == hashes["keep-mesh"], repr(r)
        ids = [x["id"] for x in d.req("GET", "/v1/scenes").json()["scenes"]]
        assert "keep-mesh" in ids and "cornell-box" in ids and "keep-box" not in ids
        assert d.req("GET", "/healthz").status == 200
    finally:
        rc, _ = d.stop()
    assert rc == 0


# ---- 6. SIGTERM during a job ----

@pytest.mark.concurrency
def test_sigterm_during_animation_job(tmp_path):
    d = Daemon(tmp_path / "data", "--threads", "2")
    try:
        s = new_session(d, width=32, height=32, params={"spp": 1})
        r = d.req("POST", s["href"] + "/renders", json_body={"animation": {"fps": 30, "frames": 5000}})
        assert r.status == 202, repr(r)
        deadline = time.monotonic() + 30
        while True:
            job = d.req("GET", r.header("Location")).json()
            if job["status"] == "running" and job["progress"]["frames_done"] >= 1:
                break
            assert time.monotonic() < deadline, job
            time.sleep(0.02)
    finally:
        rc, took = d.stop(timeout=30)
    assert rc == 0, f"exit code {rc} after {took:.1f} s\n{d.stderr()[-3000:]}"
    assert took < 30
    assert "stopped" in d.stderr(), d.stderr()[-3000:]


def test_restir_pt_session(daemon):
    """A restir_pt session: its parameters with defaults, exactly its own buffers (two 64-byte
    reservoir buffers and two G-buffers, no BDPT/SMS/SSS state), frames with per-pass times, and
    the camera moving between frames without losing the history."""
    s = new_session(daemon, method="restir_pt", width=32, height=24, seed=3, params={"spatial_neighbors": 4})
    assert s["method"] == "restir_pt"
    p = s["params"]
    assert p["spatial_neighbors"] == 4 and p["spatial_radius"] == 3 and p["temporal_cap"] == 20
    assert p["footprint"] is True and p["footprint_c"] == pytest.approx(0.02) and p["pdf_connect"] is True
    assert p["unify_di"] is True and p["rr"] is True and p["max_depth"] == 64
    # RIS NEE candidates follow the scene: plain NEE under cornell-box's one light, 4 under
    # refractive-slab's two; a value given is kept.
    assert p["nee_candidates"] == 1
    two = new_session(daemon, scene="refractive-slab", method="restir_pt", width=8, height=8)
    given = new_session(daemon, method="restir_pt", width=8, height=8, params={"nee_candidates": 3})
    assert two["params"]["nee_candidates"] == 4 and given["params"]["nee_candidates"] == 3
    # So do the converge profile's initial paths: 8 with refractive-slab's glass, 1 in the
    # all-diffuse cornell-box; the real-time default is 1 everywhere.
    assert p["candidates"] == 1 and two["params"]["candidates"] == 1
    still = [new_session(daemon, scene=sc, method="restir_pt", width=8, height=8, profile="converge")
             for sc in ("refractive-slab", "cornell-box")]
    assert [x["params"]["candidates"] for x in still] == [8, 1]
    unpaired = new_session(daemon, method="restir_pt", width=8, height=8, params={"paired_spatial": False})
    # A radius of 0 is the resolution's (20 pixels per 1080 lines, at least 3), and reported.
    by_size = [new_session(daemon, method="restir_pt", width=w, height=h, params={"spatial_radius": 0})
               for w, h in ((8, 8), (600, 270))]
    assert [x["params"]["spatial_radius"] for x in by_size] == [3, 5]
    for x in (two, given, unpaired, *by_size, *still):
        assert daemon.req("DELETE", x["href"]).status == 204
    assert s["reservoir_bytes_per_pixel"] == 64
    assert s["reservoir_bytes"] == 2 * 64 * 32 * 24 == s["buffers"]["reservoirs"]
    own = {"frame", "accumulation", "shape_changes", "reservoirs", "gbuffers", "primitive_table", "primary_hits",
           "emission"}
    assert set(s["buffers"]) == own | {"spatial_pairs"}
    assert set(unpaired["buffers"]) == own  # the pairs' scratch only with paired spatial reuse
    # One copy for both G-buffers: emission (12 bytes a pixel), edge marks (1), corners (4 a corner)
    # and the edges' key (56).
    assert s["buffers"]["emission"] == 32 * 24 * 13 + 33 * 25 * 4 + 56
    one_ray = new_session(daemon, method="restir_pt", width=8, height=8, params={"emission_samples": 1})
    assert set(one_ray["buffers"]) == own - {"emission"} | {"spatial_pairs"}  # the primary ray's own: no buffer
    assert daemon.req("DELETE", one_ray["href"]).status == 204
    first = post_frame(daemon, s, accept="application/json").json()
    assert first["passes"]["temporal_ms"] >= 0 and first["passes"]["shifts"] > 0
    moved = {"camera": {"position": [288, 273, -800]}}
    st = post_frame(daemon, s, moved, accept="application/json").json()
    passes = st["passes"]
    for key in ["gbuffer_ms", "initial_ms", "temporal_ms", "spatial_ms", "shade_ms", "shifts", "shift_failures",
                "rejected"]:
        assert key in passes, (key, passes)
    assert passes["shifts"] > first["passes"]["shifts"], "the second frame reuses the first temporally"
    assert st["nonfinite"] == 0 and st["samples"] == 32 * 24
    img = frame_rgb(daemon, s)
    assert img.shape == (24, 32, 3) and np.isfinite(img).all() and img.mean() > 0.01
    assert daemon.req("DELETE", s["href"]).status == 204


def test_bdpt_session(daemon):
    """A bdpt session: its parameters with defaults, exactly its own buffers (the light vertex
    cache and its block table, no reservoirs), and frames reporting light subpaths, cache size
    and light-traced samples."""
    s = new_session(daemon, method="bdpt", width=32, height=24, seed=3, params={"heuristic": "balance"})
    assert s["method"] == "bdpt"
    p = s["params"]
    assert p == {"max_depth": 64, "rr_depth": 3, "light_paths": 0, "lvc_capacity": 8, "heuristic": "balance"}
    assert s["reservoir_bytes"] == 0 and s["reservoir_bytes_per_pixel"] == 0
    assert set(s["buffers"]) == {"frame", "accumulation", "shape_changes", "light_vertex_cache", "lvc_blocks"}
    # 32 x 24 = 768 light subpaths: 3 blocks of 256, 8 vertices each of 68 bytes.
    assert s["buffers"]["light_vertex_cache"] == 3 * 256 * 8 * 68
    st = post_frame(daemon, s, accept="application/json").json()
    b = st["bdpt"]
    assert b["light_subpaths"] == 32 * 24 and b["lvc_vertices"] > 0 and b["lvc_dropped"] == 0
    assert b["light_traced"] > 0 and b["connections"] > 0 and "passes" not in st
    assert st["nonfinite"] == 0 and st["samples"] == 32 * 24
    img = frame_rgb(daemon, s)
    assert img.shape == (24, 32, 3) and np.isfinite(img).all() and img.mean() > 0.01
    assert daemon.req("DELETE", s["href"]).status == 204


@pytest.mark.parametrize("params,field", [
    ({"lvc_capacity": 0}, "/params/lvc_capacity"),
    ({"heuristic": "max"}, "/params/heuristic"),
    ({"max_depth": 0}, "/params/max_depth"),
    ({"spp": 4}, "/params/spp"),
])
def test_bdpt_bad_params(daemon, params, field):
    r = daemon.req("POST", f"{CORNELL}/sessions", json_body={"method": "bdpt", "width": 8, "height": 8,
                                                             "params": params})
    assert_problem(r, 422, "invalid-field", field)


def test_restir_bdpt_session(daemon):
    """A restir_bdpt session: its parameters with defaults, exactly its own buffers (three
    reservoirs per pixel — the non-caustic one with its sample's reconnection — the light-traced
    samples, the caustic shifts, the buckets), planned bytes equal to allocated ones, and frames
    reporting light subpaths, light-traced and caustic samples, shift failures by kind and
    reservoir bytes."""
    s = new_session(daemon, scene="caustic-sphere", method="restir_bdpt", width=32, height=24, seed=3,
                    params={"heuristic": "balance", "reuse": False})
    assert s["method"] == "restir_bdpt"
    # The defaults (the resolution's radius at 32 x 24 is the least, 3 pixels).
    assert s["params"] == {"variant": "lightweight", "max_depth": 64, "rr_depth": 3, "light_paths": 0,
                           "lt_capacity": 8, "lvc_capacity": 8, "heuristic": "balance", "caustic_temporal": True, "temporal_cap": 20,
                           "moving_cap": 1, "reuse": False, "reuse_temporal": True, "history_check": True,
                           "emission_samples": 16, "spatial_neighbors": 2,
                           "spatial_rounds": 1, "spatial_radius": 3,
                           "paired_spatial": True, "expected_shading": True, "camera_reconnect": True, "copy_mis": False,
                           "reject_unshiftable": False}
    assert set(s["buffers"]) == {"frame", "accumulation", "shape_changes", "reservoirs", "light_traced_samples",
                                 "caustic_shifts", "pixel_buckets", "light_blocks"}
    n = 32 * 24
    assert s["reservoir_bytes_per_pixel"] == 88 and s["reservoir_bytes"] == (88 + 2 * 28) * n
    # 768 light subpaths: 3 blocks of 256, 8 samples of 24 bytes each, per-block and sorted.
    assert s["buffers"]["light_traced_samples"] == 2 * 3 * 256 * 8 * 24
    assert s["memory_bytes"] == sum(s["buffers"].values())
    for i in range(3):
        st = post_frame(daemon, s, accept="application/json").json()
        b = st["restir_bdpt"]
        assert b["light_subpaths"] == n and b["light_vertices"] >= b["light_traced"] > 0 and b["lt_dropped"] == 0
        assert b["lt_unshiftable"] == 0
        assert b["caustic_samples"] > 0 and b["camera_candidates"] > 0 and b["reservoir_bytes"] == (88 + 2 * 28) * n
        assert set(b["shift_failures"]) == {"replay", "not_caustic", "inverse"}
        assert (b["caustic_shifts"] > 0) == (i > 0), (i, b)
        assert st["nonfinite"] == 0 and st["samples"] == n and "passes" not in st and "bdpt" not in st
    img = frame_rgb(daemon, s)
    assert img.shape == (24, 32, 3) and np.isfinite(img).all() and img.mean() > 0.01
    assert daemon.req("DELETE", s["href"]).status == 204


def test_restir_bdpt_reuse_session_buffers(daemon):
    """With reuse a restir_bdpt session adds exactly the reuse's buffers: two more non-caustic
    reservoirs, the G-buffers (this frame's and, for the history check, the previous one's; one
    without temporal reuse), the spatial pairs' scratch and the per-pixel x_2 cache of 2 x 116
    bytes (the reverse hybrid shift's replayed light vertex, this frame's and the previous one's);
    its memory is their sum."""
    s = new_session(daemon, scene="caustic-sphere", method="restir_bdpt", width=32, height=24, seed=3,
                    params={"reuse": True})
    assert s["params"]["spatial_radius"] == 3  # the resolution's radius (at least 3 pixels)
    wide = new_session(daemon, scene="caustic-sphere", method="restir_bdpt", width=600, height=270,
                       params={"reuse": False})
    assert wide["params"]["spatial_radius"] == 5  # 20 pixels per 1080 of the shorter side
    assert daemon.req("DELETE", wide["href"]).status == 204
    n = 32 * 24
    assert set(s["buffers"]) == {"frame", "accumulation", "shape_changes", "reservoirs", "light_traced_samples",
                                 "caustic_shifts", "pixel_buckets", "light_blocks", "gbuffers", "spatial_pairs",
                                 "light_x2_cache", "emission"}
    assert s["buffers"]["light_x2_cache"] == 2 * 116 * n
    assert s["buffers"]["gbuffers"] == 2 * 40 * n
    # The emission seen directly (gbuffer.h), one copy for both G-buffers: 12 + 1 bytes a pixel, 4 a
    # pixel corner and the edges' key (56).
    assert s["buffers"]["emission"] == 13 * n + 33 * 25 * 4 + 56
    spatial = new_session(daemon, scene="caustic-sphere", method="restir_bdpt", width=32, height=24,
                          params={"reuse_temporal": False})
    assert spatial["buffers"]["gbuffers"] == 40 * n
    assert daemon.req("DELETE", spatial["href"]).status == 204
    off = new_session(daemon, scene="caustic-sphere", method="restir_bdpt", width=32, height=24,
                      params={"reuse": False})
    assert not {"gbuffers", "spatial_pairs", "emission"} & set(off["buffers"])
    assert daemon.req("DELETE", off["href"]).status == 204
    assert s["reservoir_bytes"] == (3 * 88 + 2 * 28) * n and s["reservoir_bytes_per_pixel"] == 88
    assert s["memory_bytes"] == sum(s["buffers"].values())
    assert daemon.req("DELETE", s["href"]).status == 204


@pytest.mark.parametrize("params,field", [
    ({"variant": "full", "reuse": True, "copy_mis": True}, "/params/copy_mis"),
    ({"variant": "heavy"}, "/params/variant"),
    ({"lt_capacity": 0}, "/params/lt_capacity"),
    ({"temporal_cap": 0}, "/params/temporal_cap"),
    ({"moving_cap": 0}, "/params/moving_cap"),
    ({"emission_samples": 0}, "/params/emission_samples"),
    ({"emission_samples": 300}, "/params/emission_samples"),
    ({"caustic_temporal": 1}, "/params/caustic_temporal"),
    ({"heuristic": "max"}, "/params/heuristic"),
    ({"lvc_capacity": 0}, "/params/lvc_capacity"),
    ({"lvc_size": 8}, "/params/lvc_size"),
    ({"spatial_neighbors": 33}, "/params/spatial_neighbors"),
    ({"spatial_radius": -1}, "/params/spatial_radius"),
    ({"spatial_radius": 257}, "/params/spatial_radius"),
    ({"spatial_rounds": 0}, "/params/spatial_rounds"),
    ({"copy_mis": True, "reuse": False}, "/params/copy_mis"),
    ({"reject_unshiftable": "yes"}, "/params/reject_unshiftable"),
])
def test_restir_bdpt_bad_params(daemon, params, field):
    r = daemon.req("POST", f"{CORNELL}/sessions", json_body={"method": "restir_bdpt", "width": 8, "height": 8,
                                                             "params": params})
    assert_problem(r, 422, "invalid-field", field)


def test_restir_bdpt_refuses_translucent(daemon):
    """restir_bdpt does not sample subsurface scattering: refused naming /method, as bdpt."""
    r = daemon.req("POST", "/v1/scenes/translucent/sessions", json_body={"method": "restir_bdpt", "width": 8,
                                                                        "height": 8})
    assert_problem(r, 422, "invalid-field", "/method")


@pytest.mark.parametrize("params,field", [
    ({"spatial_neighbors": 65}, "/params/spatial_neighbors"),
    ({"reject_normal_cos": 1.5}, "/params/reject_normal_cos"),
    ({"reject_depth": -0.1}, "/params/reject_depth"),
    ({"temporal_cap_replay": 1001}, "/params/temporal_cap_replay"),
    ({"jitter_walk": 0.6}, "/params/jitter_walk"),
    ({"jitter_walk": -0.01}, "/params/jitter_walk"),
    ({"emission_samples": 0}, "/params/emission_samples"),
    ({"emission_samples": 257}, "/params/emission_samples"),
    ({"footprint_c": 0}, "/params/footprint_c"),
    ({"max_depth": 0}, "/params/max_depth"),
    ({"temporal": 1}, "/params/temporal"),
    ({"spp": 4}, "/params/spp"),
])
def test_restir_pt_bad_params(daemon, params, field):
    r = daemon.req("POST", f"{CORNELL}/sessions", json_body={"method": "restir_pt", "width": 8, "height": 8,
                                                             "params": params})
    assert_problem(r, 422, "invalid-field", field)


def test_restir_sss_session(daemon):
    """A restir_sss session on the translucent scene: its parameters with defaults, exactly its
    own buffers (two 72-byte reservoir buffers and two G-buffers, and the rest's restir_pt session
    and frame, which `rest` pt goes without), frames with per-pass times and reuse; bad values and
    unknown keys are refused naming the field."""
    s = new_session(daemon, scene="translucent", method="restir_sss", width=24, height=24, seed=2,
                    params={"shift": "delayed"})
    p = s["params"]
    assert p["shift"] == "delayed" and p["candidates"] == 1 and p["spatial_neighbors"] == 4
    assert p["temporal_cap"] == 20 and p["kappa_orientation"] == pytest.approx(0.5) and p["spatial_radius"] == 0
    assert p["rest"] == "restir_pt"  # by_scene, resolved
    assert s["reservoir_bytes_per_pixel"] == 72
    assert s["reservoir_bytes"] == 2 * 72 * 24 * 24 == s["buffers"]["reservoirs"]
    own = {"frame", "accumulation", "shape_changes", "reservoirs", "gbuffers", "primary_hits", "spatial_pairs"}
    assert set(s["buffers"]) == own | {"rest_reservoirs", "rest_gbuffers", "rest_primitive_table",
                                       "rest_spatial_pairs", "rest_frame"}
    assert s["buffers"]["rest_reservoirs"] == 2 * 64 * 24 * 24
    post_frame(daemon, s, accept="application/json")
    t0 = time.monotonic()
    st = post_frame(daemon, s, accept="application/json").json()
    wall_ms = (time.monotonic() - t0) * 1e3
    # The rest's time is part of the frame's, which the request's wall time bounds.
    assert st["passes"]["shifts"] > 0 and st["nonfinite"] == 0 and 0 < st["rest_ms"] < st["render_ms"] < wall_ms
    img = frame_rgb(daemon, s)
    assert img.shape == (24, 24, 3) and np.isfinite(img).all() and img.mean() > 0.01
    assert daemon.req("DELETE", s["href"]).status == 204
    for params, field in [({"shift": "sequential", "spatial_neighbors": 5}, "/params/spatial_neighbors"),
                          ({"shift": 3}, "/params/shift"), ({"index_shortcut": True}, "/params/index_shortcut"),
                          ({"candidates": 0}, "/params/candidates"), ({"spp": 2}, "/params/spp"),
                          ({"rest": "bdpt"}, "/params/rest"), ({"rest": "restir_pt", "max_depth": 0}, "/params/max_depth")]:
        r = daemon.req("POST", "/v1/scenes/translucent/sessions",
                       json_body={"method": "restir_sss", "width": 8, "height": 8, "params": params})
        assert_problem(r, 422, "invalid-field", field)
    s = new_session(daemon, scene="translucent", method="restir_sss", width=8, height=8, params={"rest": "pt"})
    assert s["params"]["rest"] == "pt" and set(s["buffers"]) == own
    assert daemon.req("DELETE", s["href"]).status == 204


def test_restir_sms_session(daemon):
    """A restir_sms session on refractive-slab: its parameters with defaults, exactly its own
    buffers (two 64-byte reservoir buffers, two G-buffers, two receiver buffers, the prior, the
    spatial pairs, and the rest's restir_pt session and frame; without the prior under the sms
    sampler, without the pairs unpaired, without the rest's with `rest` pt), frames with per-pass
    times, the rest's time, the manifold shifts' counters and [SMS-SSP Table 1]'s; bad values are
    refused naming the field."""
    s = new_session(daemon, scene="refractive-slab", method="restir_sms", width=24, height=24, seed=2,
                    params={"bernoulli_cap": 0})
    p = s["params"]
    assert p["shift_iterations"] == 5 and p["spatial_neighbors"] == 1 and p["spatial_radius"] == 30
    assert p["temporal_cap"] == 20 and p["bernoulli_cap"] == 0 and p["tiles"] == 16 and p["sampler"] == "ssp"
    assert p["paired_spatial"] is True and p["jitter_walk"] == pytest.approx(0.1)
    assert p["light_reservoirs"] == 2  # one per light, as the session resolved it on the slab
    assert s["reservoir_bytes_per_pixel"] == 2 * 64
    assert s["reservoir_bytes"] == 2 * 2 * 64 * 24 * 24 == s["buffers"]["reservoirs"]
    assert p["rest"] == "restir_pt"  # by_scene, resolved: the slab has no translucent material
    own = {"frame", "accumulation", "shape_changes", "reservoirs", "gbuffers", "receivers"}
    rest = {"rest_reservoirs", "rest_gbuffers", "rest_primitive_table", "rest_spatial_pairs", "rest_frame"}
    assert set(s["buffers"]) == own | {"prior", "spatial_pairs"} | rest
    assert s["buffers"]["rest_reservoirs"] == 2 * 64 * 24 * 24 and s["buffers"]["rest_frame"] == 12 * 24 * 24
    # 2 x 2 blocks of 16 x 16 pixels, 8 pair entries of 168 bytes, in 1 + prior_frames tables.
    assert p["prior_frames"] == 4 and s["buffers"]["prior"] == (1 + 4) * 2 * 2 * 8 * 168
    for params, extra in [({"sampler": "sms"}, {"spatial_pairs"} | rest),
                          ({"paired_spatial": False}, {"prior"} | rest),
                          ({"rest": "pt"}, {"prior", "spatial_pairs"}),
                          ({"caustics_only": True}, {"prior", "spatial_pairs"})]:
        t = new_session(daemon, scene="refractive-slab", method="restir_sms", width=8, height=8, params=params)
        assert set(t["buffers"]) == own | extra, params
        assert t["params"]["rest"] == ("restir_pt" if extra & rest else "pt"), params
        assert daemon.req("DELETE", t["href"]).status == 204
    for asked, kept in [(1, 1), (3, 3), (0, 2)]:
        t = new_session(daemon, scene="refractive-slab", method="restir_sms", width=8, height=8,
                        params={"light_reservoirs": asked})
        assert t["params"]["light_reservoirs"] == kept and t["buffers"]["reservoirs"] == 2 * kept * 64 * 8 * 8
        assert daemon.req("DELETE", t["href"]).status == 204
    post_frame(daemon, s, accept="application/json")
    t0 = time.monotonic()
    st = post_frame(daemon, s, accept="application/json").json()
    wall_ms = (time.monotonic() - t0) * 1e3
    assert st["passes"]["shifts"] > 0 and st["nonfinite"] == 0
    assert st["manifold_shift"]["newton"] > 0 and 0 < st["manifold_shift"]["success_rate"] <= 1
    assert st["sms"]["solutions"] > 0 and st["prior"]["samples"] > 0 and 0 < st["rest_ms"] < st["render_ms"] < wall_ms
    img = frame_rgb(daemon, s)
    assert img.shape == (24, 24, 3) and np.isfinite(img).all() and img.mean() > 0.01
    assert daemon.req("DELETE", s["href"]).status == 204
    for params, field in [({"shift_iterations": 0}, "/params/shift_iterations"), ({"tiles": 2}, "/params/tiles"),
                          ({"spatial_radius": 0}, "/params/spatial_radius"), ({"spp": 2}, "/params/spp"),
                          ({"sampler": "bdpt"}, "/params/sampler"), ({"paired_spatial": 1}, "/params/paired_spatial"),
                          ({"jitter_walk": 0.6}, "/params/jitter_walk"), ({"jitter_walk": -0.1}, "/params/jitter_walk"),
                          ({"light_reservoirs": 9}, "/params/light_reservoirs"),
                          ({"light_reservoirs": -1}, "/params/light_reservoirs"),
                          ({"prior_frames": 0}, "/params/prior_frames"), ({"prior_frames": 17}, "/params/prior_frames"),
                          ({"rest": "bdpt"}, "/params/rest"), ({"rest": 1}, "/params/rest"),
                          ({"rest": "restir_pt", "max_depth": 127}, "/params/max_depth")]:
        r = daemon.req("POST", "/v1/scenes/refractive-slab/sessions",
                       json_body={"method": "restir_sms", "width": 8, "height": 8, "params": params})
        assert_problem(r, 422, "invalid-field", field)


@pytest.mark.parametrize("method,schema", [("pt", "PtParams"), ("restir_pt", "RestirPtParams"), ("bdpt", "BdptParams"),
                                           ("restir_bdpt", "RestirBdptParams"),
                                           ("sms", "SmsParams"), ("sms_ssp", "SmsSspParams"),
                                           ("restir_sss", "RestirSssParams"), ("restir_sms", "RestirSmsParams")])
def test_session_echoes_every_method_param(daemon, method, schema):
    """A session object names every param its method takes (the ones openapi.yaml documents),
    and sending them back creates a session with the same params: no param is accepted and then
    left out, or echoed under a name the parser refuses."""
    import yaml
    doc = yaml.safe_load((ROOT / "protocol" / "openapi.yaml").read_text())
    keys = set(doc["components"]["schemas"][schema]["properties"])
    s = new_session(daemon, method=method, width=8, height=8)
    assert set(s["params"]) == keys, (method, set(s["params"]) ^ keys)
    again = new_session(daemon, method=method, width=8, height=8, params=s["params"])
    assert again["params"] == s["params"]
    for x in (s, again):
        assert daemon.req("DELETE", x["href"]).status == 204
