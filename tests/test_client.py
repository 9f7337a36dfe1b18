"""Tests of the Python client (clients/python/restir.py) that need no daemon: argument parsing,
orbit keys, problem parsing, and the retry and scale-out recovery logic against a small fake
server (http.server on 127.0.0.1, port chosen by the OS) that plays the parts of the API the
client uses."""
import io
import json
import math
import os
import re
import shutil
import subprocess
import sys
import threading
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "clients" / "python"))
import restir  # noqa: E402

CAMERA = {"position": [278.0, 273.0, -800.0], "look_at": [278.0, 273.0, 0.0], "up": [0.0, 1.0, 0.0],
          "fov_deg": 39.3077}
SCENE = {"camera": CAMERA, "materials": {"w": {"type": "diffuse", "albedo": [0.5, 0.5, 0.5]}},
         "shapes": [{"type": "mesh", "material": "w", "file": "m.ply"}]}
P = "urn:restird:problem:"


# ---- a fake daemon ----

class FakeDaemon:
    """Just enough of restird: scenes, assets, sessions, frames, jobs. fail_over() forgets every
    uploaded scene and every session, as a fresh daemon behind the proxy would; built-in scenes
    stay (every daemon has the library)."""

    BUILTIN = {"lib-box"}

    def __init__(self):
        self.lock = threading.Lock()
        self.log = []               # (method, path, headers, body)
        self.scenes = {}
        self.assets = {}
        self.sessions = {}          # sid -> {"scene", "body", "frames"}
        self.jobs = {}              # rid -> job
        self.refs = set()
        self.next_id = 0
        self.busy = {}              # (method, path regex) -> remaining 503 answers
        self.refuse = {}            # (method, path regex) -> (status, slug, detail), always
        self.frames_kept = 16
        self.frames_before = 0      # frames a new session has rendered before a job's

    def fail_over(self):
        with self.lock:
            self.scenes.clear()
            self.assets.clear()
            self.sessions.clear()
            self.jobs.clear()

    def calls(self, method=None):
        return [(m, p, h, b) for (m, p, h, b) in self.log if method is None or m == method]

    def job_view(self, sess, job):
        """The job as the daemon shows it: only the frames the session still keeps."""
        numbers = [int(h.rsplit("/", 1)[1]) for h in job["frames"]]
        kept = [n for n in numbers if n >= sess["frames"] - self.frames_kept]
        return dict(job, frames=[h for h in job["frames"] if int(h.rsplit("/", 1)[1]) in kept],
                    frames_kept=[kept[0], kept[-1]] if kept else None, frames_evicted=len(numbers) - len(kept))

    def _id(self, prefix):
        self.next_id += 1
        return "%s%d" % (prefix, self.next_id)

    @staticmethod
    def problem(status, slug, detail, instance, field=None, headers=None):
        body = {"type": P + slug, "title": slug.replace("-", " ").capitalize(), "status": status,
                "detail": detail, "instance": instance}
        if field is not None:
            body["field"] = field
        return status, dict(headers or {}, **{"Content-Type": "application/problem+json"}), \
            json.dumps(body).encode()

    @staticmethod
    def ok(status, obj, headers=None):
        return status, dict(headers or {}, **{"Content-Type": "application/json"}), json.dumps(obj).encode()

    def session_obj(self, sid):
        s = self.sessions[sid]
        body = s["body"]
        return {"id": sid, "scene": s["scene"], "method": body.get("method", "pt"),
                "width": body.get("width", 256), "height": body.get("height", 256),
                "seed": body.get("seed", 0), "params": body.get("params", {}),
                "frames_rendered": s["frames"], "busy": False, "camera": CAMERA,
                "reservoir_bytes": 0, "buffers": {"accumulation": 1}, "memory_bytes": 1,
                "frames_kept": self.frames_kept,
                "href": "/v1/scenes/%s/sessions/%s" % (s["scene"], sid)}

    def frame_answer(self, sid, n, accept):
        href = "/v1/scenes/%s/sessions/%s/frames/%d" % (self.sessions[sid]["scene"], sid, n)
        hdrs = {"X-Frame": str(n), "X-Render-Ms": "1.5", "Content-Location": href, "ETag": '"f%d"' % n}
        if accept == "application/json":
            return self.ok(200, {"frame": n, "time_s": 0, "render_ms": 1.5, "href": href}, hdrs)
        ctype = "image/png" if accept == "image/png" else "image/x-exr"
        return 200, dict(hdrs, **{"Content-Type": ctype}), b"IMG:%s:%d" % (ctype.encode(), n)

    def handle(self, method, path, headers, body):
        with self.lock:
            self.log.append((method, path, headers, body))
            for (m, rx), left in list(self.busy.items()):
                if m == method and re.fullmatch(rx, path.split("?")[0]) and left > 0:
                    self.busy[(m, rx)] = left - 1
                    return self.problem(503, "busy", "render queue full", path, headers={"Retry-After": "0"})
            for (m, rx), (status, slug, detail) in self.refuse.items():
                if m == method and re.fullmatch(rx, path.split("?")[0]):
                    return self.problem(status, slug, detail, path)
            return self._route(method, path, headers, body)

    def _route(self, method, full, headers, body):
        path, _, query = full.partition("?")
        seg = path.strip("/").split("/")
        accept = headers.get("Accept") or "image/x-exr"
        if path == "/healthz":
            return self.ok(200, {"status": "ok"})
        if path == "/readyz":
            return self.ok(200, {"status": "ready"})
        if path == "/v1/limits":
            return self.ok(200, {"max_keys": 4096, "frames_kept": self.frames_kept})
        if path == "/v1/methods":
            return self.ok(200, {"methods": [{"name": n, "capabilities": {"takes_spp": n in ("pt", "sms")}}
                                             for n in ("pt", "sms", "restir_pt", "bdpt")]})
        if path == "/v1/scenes" and method == "GET":
            ids = sorted(set(self.scenes) | self.BUILTIN)
            return self.ok(200, {"scenes": [{"id": i, "builtin": i in self.BUILTIN, "hash": "0",
                                             "shapes": 1, "triangles": 2, "emitters": 0,
                                             "sessions": 0} for i in ids]})
        if len(seg) < 3 or seg[:2] != ["v1", "scenes"]:
            return self.problem(404, "not-found", "no such route", path)
        scene = seg[2]
        rest = seg[3:]
        if method == "PUT" and not rest:
            if headers.get("Content-Type") != "application/json":
                return self.problem(415, "unsupported-media-type", "need JSON", path)
            created = scene not in self.scenes
            self.scenes[scene] = body
            return self.ok(201 if created else 200, {"id": scene, "replaced": False})
        if method == "PUT" and len(rest) == 2 and rest[0] == "assets":
            self.assets[(scene, rest[1])] = body
            return 201, {}, b""
        if scene not in self.scenes and scene not in self.BUILTIN:
            return self.problem(404, "scene-not-loaded", "this daemon does not hold scene " + scene, path)
        if len(rest) == 2 and rest[0] == "references" and method == "DELETE":
            if rest[1] not in self.refs:
                return self.problem(404, "not-found", "no such reference", path)
            self.refs.discard(rest[1])
            return 204, {}, b""
        if rest == ["sessions"] and method == "POST":
            req = json.loads(body or b"{}")
            sid = self._id("s")
            self.sessions[sid] = {"scene": scene, "body": req, "frames": self.frames_before}
            return self.ok(201, self.session_obj(sid), {"Location": "/v1/scenes/%s/sessions/%s" % (scene, sid)})
        if len(rest) >= 2 and rest[0] == "sessions":
            sid = rest[1]
            if sid not in self.sessions:
                return self.problem(404, "not-found", "no such session", path)
            sess = self.sessions[sid]
            tail = rest[2:]
            if not tail and method == "GET":
                return self.ok(200, self.session_obj(sid))
            if not tail and method == "DELETE":
                del self.sessions[sid]
                return 204, {}, b""
            if tail == ["frames"] and method == "POST":
                n = sess["frames"]
                sess["frames"] += 1
                return self.frame_answer(sid, n, accept)
            if len(tail) == 2 and tail[0] == "frames" and method == "GET":
                n = int(tail[1])
                if n >= sess["frames"]:
                    return self.problem(404, "not-found", "no such frame", path)
                if n < sess["frames"] - self.frames_kept:
                    return self.problem(410, "frame-evicted", "frame no longer kept", path)
                return self.frame_answer(sid, n, accept)
            if tail == ["renders"] and method == "POST":
                req = json.loads(body)
                key = headers.get("Idempotency-Key")
                for job in self.jobs.values():
                    if key and job.get("_key") == key:
                        return self.ok(202, job)
                rid = self._id("r")
                frames = req["animation"]["frames"]
                hrefs = []
                for _ in range(frames):
                    hrefs.append("/v1/scenes/%s/sessions/%s/frames/%d" % (scene, sid, sess["frames"]))
                    sess["frames"] += 1
                job = {"id": rid, "kind": "animation", "status": "done",
                       "progress": {"frames_done": frames, "frames_total": frames}, "frames": hrefs,
                       "reference": req.get("reference"), "error": None, "_key": key, "_req": req}
                self.jobs[rid] = job
                loc = "/v1/scenes/%s/sessions/%s/renders/%s" % (scene, sid, rid)
                return self.ok(202, job, {"Location": loc})
            if len(tail) == 2 and tail[0] == "references" and method == "POST":
                rid = self._id("r")
                self.refs.add(tail[1])
                job = {"id": rid, "kind": "reference", "status": "done",
                       "progress": {"frames_done": 1, "frames_total": 1}, "frames": [],
                       "reference": tail[1], "error": None, "_req": json.loads(body or b"{}")}
                self.jobs[rid] = job
                return self.ok(202, job, {"Location": "/v1/scenes/%s/sessions/%s/renders/%s" % (scene, sid, rid)})
            if len(tail) >= 2 and tail[0] == "renders":
                job = self.jobs.get(tail[1])
                if job is None:
                    return self.problem(404, "not-found", "no such job", path)
                if len(tail) == 2:
                    return self.ok(200, self.job_view(sess, job))
                if tail[2:] == ["metrics"]:
                    rows = [{"frame": i, "time_s": i / 30, "render_ms": 1.0, "mape": 0.5 / (i + 1),
                             "rmse": 0.1, "relmse": 0.2} for i in range(len(job["frames"]))]
                    if accept == "text/csv":
                        text = "frame,time_s,render_ms,mape,rmse,relmse\n" + "".join(
                            "%d,%g,%g,%g,%g,%g\n" % tuple(r.values()) for r in rows)
                        return 200, {"Content-Type": "text/csv"}, text.encode()
                    return self.ok(200, rows)
            return self.problem(404, "not-found", "no such route", path)
        return self.problem(404, "not-found", "no such route", path)


@pytest.fixture
def fake():
    daemon = FakeDaemon()

    class Handler(BaseHTTPRequestHandler):
        def _serve(self):
            n = int(self.headers.get("Content-Length") or 0)
            body = self.rfile.read(n) if n else b""
            status, hdrs, data = daemon.handle(self.command, self.path, dict(self.headers), body)
            self.send_response(status)
            hdrs = dict(hdrs)
            hdrs.setdefault("X-Request-Id", "req-%d" % len(daemon.log))
            hdrs.setdefault("X-Served-By", "fake:0")
            for k, v in hdrs.items():
                self.send_header(k, v)
            self.send_header("Content-Length", str(len(data)))
            self.end_headers()
            self.wfile.write(data)

        do_GET = do_PUT = do_POST = do_DELETE = _serve

        def log_message(self, *args):
            pass

    server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
    server.daemon_threads = True
    thread = threading.Thread(target=server.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True)
    thread.start()
    daemon.url = "http://127.0.0.1:%d" % server.server_address[1]
    try:
        yield daemon
    finally:
        server.shutdown()
        server.server_close()


def client_for(fake, **kw):
    notes = []
    c = restir.Client(fake.url, timeout=10, log=notes.append, **kw)
    c.notes = notes
    return c


# ---- problems ----

def test_problem_body_becomes_error_fields():
    body = json.dumps({"type": P + "invalid-field", "title": "Invalid field", "status": 422,
                       "detail": "expected a number, got string", "instance": "/v1/scenes/x/sessions",
                       "field": "/width"}).encode()
    e = restir.RestirError.from_response(422, {"X-Request-Id": "abc", "X-Served-By": "d1"}, body)
    assert (e.status, e.type, e.slug, e.detail, e.field) == (
        422, P + "invalid-field", "invalid-field", "expected a number, got string", "/width")
    assert (e.request_id, e.served_by, e.instance) == ("abc", "d1", "/v1/scenes/x/sessions")
    assert "invalid-field" in str(e) and "/width" in str(e)


def test_problem_limit_whole_body_field_and_retry_after():
    body = json.dumps({"type": P + "body-too-large", "title": "Body too large", "status": 413,
                       "detail": "over 1 MiB", "instance": "/v1/scenes/x", "field": "", "limit": 1048576}).encode()
    e = restir.RestirError.from_response(413, {"Retry-After": "7"}, body)
    assert e.limit == 1048576 and e.field == "" and e.retry_after == 7.0
    assert '(field "")' in str(e) and "limit 1048576" in str(e)


def test_error_body_that_is_not_a_problem():
    e = restir.RestirError.from_response(502, {}, b"<html>bad gateway</html>")
    assert e.status == 502 and e.type is None and "bad gateway" in e.detail
    e = restir.RestirError.from_response(500, {}, b"")
    assert e.status == 500 and e.detail is None


def test_http_status_wins_over_body_status_and_job_errors_parse():
    e = restir.RestirError.from_response(404, {}, json.dumps({"type": P + "not-found", "status": 200}).encode())
    assert e.status == 404
    e = restir.RestirError.from_problem({"type": P + "internal", "status": 500, "detail": "boom", "job": "r1"})
    assert e.slug == "internal" and e.detail == "boom"


def test_retry_after_forms():
    assert restir.parse_retry_after("3") == 3.0
    assert restir.parse_retry_after(None) is None
    assert restir.parse_retry_after("soon") is None
    assert restir.parse_retry_after("Wed, 21 Oct 2015 07:28:00 GMT") == 0.0  # in the past


# ---- argument parsing ----

def test_frame_arguments():
    a = restir.build_parser().parse_args(
        ["--server", "http://h:1", "frame", "cornell-box", "-o", "x.exr", "--size", "128x64",
         "--spp", "8", "--seed", "3", "--png", "--exposure", "-1.5"])
    assert (a.server, a.command, a.scene, a.output) == ("http://h:1", "frame", "cornell-box", "x.exr")
    assert a.size == (128, 64) and a.spp == 8 and a.seed == 3 and a.png and a.exposure == -1.5
    a = restir.build_parser().parse_args(["frame", "s", "-o", "y.exr"])
    assert a.size == (256, 256) and a.spp is None and a.method == "pt" and not a.png
    assert restir._session_params(a, _registry(("pt", True))) == {"spp": 4}


def _registry(*methods):
    """A method registry as Client.methods() returns it: (name, takes_spp) pairs."""
    return {name: {"name": name, "capabilities": {"takes_spp": spp}} for name, spp in methods}


@pytest.mark.parametrize("argv,params", [
    (["frame", "s", "-o", "x"], {"spp": 4}),
    (["frame", "s", "-o", "x", "--method", "sms_ssp"], {"spp": 4}),
    (["frame", "s", "-o", "x", "--method", "restir_sms"], {}),
    (["frame", "s", "-o", "x", "--method", "bdpt"], {}),
    (["frame", "s", "-o", "x", "--method", "restir_pt", "--spp", "2"], {"spp": 2}),
    (["frame", "s", "-o", "x", "--method", "unknown"], {}),
    (["metrics", "s", "-o", "m.csv", "--method", "restir_sss"], {}),
    (["metrics", "s", "-o", "m.csv"], {"spp": 1}),
])
def test_session_params_send_spp_only_to_methods_that_take_it(argv, params):
    """Without --spp the client sends spp only to the methods whose registry entry says they take
    it (the others refuse the key with a 422 at /params/spp)."""
    registry = _registry(("pt", True), ("sms_ssp", True), ("restir_sms", False), ("bdpt", False),
                         ("restir_pt", False), ("restir_sss", False))
    assert restir._session_params(restir.build_parser().parse_args(argv), registry) == params


def test_spp_rule_follows_the_registry():
    """The rule is the registry's, not a list of the client's own: a method whose entry gains
    takes_spp gets spp without a change to the client."""
    a = restir.build_parser().parse_args(["frame", "s", "-o", "x", "--method", "restir_pt"])
    assert restir._session_params(a, _registry(("restir_pt", False))) == {}
    assert restir._session_params(a, _registry(("restir_pt", True))) == {"spp": 4}
    # With --spp the registry is not needed (nor asked for: a daemon without it still works).
    a = restir.build_parser().parse_args(["frame", "s", "-o", "x", "--method", "restir_pt", "--spp", "2"])
    assert restir._session_params(a, lambda: pytest.fail("fetched the registry")) == {"spp": 2}


@pytest.mark.parametrize("command", [["frame", "s", "-o", "x"], ["orbit", "s", "-o", "d"], ["metrics", "s", "-o", "m"]])
def test_profile_reaches_the_session(fake, command):
    """--profile is sent as the protocol spells it (restir render's spelling on the command line);
    without it `frame` (one frame of a fresh session: a still image) sends converge and the others
    none (the daemon's default, real_time). A session recreated after a fail-over is made with the
    same body, so it keeps the profile."""
    c = client_for(fake)
    c.upload_scene("s", SCENE)
    p = restir.build_parser()
    default = "converge" if command[0] == "frame" else None
    for given, sent in ([], default), (["--profile", "converge"], "converge"), (["--profile", "real-time"], "real_time"):
        args = p.parse_args(command + ["--method", "restir_pt", "--spp", "1"] + given)
        s = restir._make_session(c, args)
        assert s.create_body.get("profile") == sent and json.loads(fake.log[-1][3]).get("profile") == sent


def test_other_commands_arguments():
    p = restir.build_parser()
    a = p.parse_args(["orbit", "s", "--frames", "12", "-o", "d", "--center", "1,2,3", "--radius", "5"])
    assert a.frames == 12 and a.center == [1.0, 2.0, 3.0] and a.radius == 5.0 and a.fps == 30.0
    a = p.parse_args(["metrics", "s", "--reference-spp", "256", "--frames", "4", "-o", "m.csv"])
    assert a.reference_spp == 256 and a.frames == 4 and a.spp is None and a.spp_default == 1
    assert a.reference_method == "pt"
    a = p.parse_args(["metrics", "s", "-o", "m.csv", "--reference-method", "sms"])
    assert a.reference_method == "sms"
    a = p.parse_args(["upload", "id", "scene.json", "a.ply", "b.obj"])
    assert a.scene_id == "id" and a.assets == ["a.ply", "b.obj"]


@pytest.mark.parametrize("argv", [
    [], ["frame"], ["frame", "s"], ["frame", "s", "-o", "x", "--size", "12"],
    ["frame", "s", "-o", "x", "--size", "0x4"], ["frame", "s", "-o", "x", "--spp", "0"],
    ["orbit", "s", "-o", "d", "--center", "1,2"], ["nonsense"], ["frame", "s", "-o", "x", "--exposure", "nan"],
    ["metrics", "s", "-o", "m.csv", "--reference-method", "bdpt"],
    ["frame", "s", "-o", "x", "--profile", "real_time"], ["metrics", "s", "-o", "m.csv", "--profile", "fast"],
])
def test_usage_errors_exit_2(argv, capsys):
    with pytest.raises(SystemExit) as exc:
        restir.main(argv)
    assert exc.value.code == 2


# ---- orbit keys ----

def dist(a, b):
    return math.sqrt(sum((x - y) ** 2 for x, y in zip(a, b)))


def test_orbit_keys_circle_around_look_at():
    keys, interp = restir.orbit_keys(CAMERA, 30, 30.0)
    assert interp == "linear" and len(keys) == 30
    assert keys[0]["position"] == CAMERA["position"]          # first key = the scene camera
    r0 = dist(CAMERA["position"], CAMERA["look_at"])
    for i, k in enumerate(keys):
        assert k["t"] == i / 30.0                              # frame i renders at i / fps
        assert k["look_at"] == CAMERA["look_at"]
        assert dist(k["position"], CAMERA["look_at"]) == pytest.approx(r0, rel=1e-12)
        assert k["position"][1] == pytest.approx(CAMERA["position"][1], abs=1e-9)   # horizontal
    assert all(b["t"] > a["t"] for a, b in zip(keys, keys[1:]))
    # a quarter of the way round, the camera is on the side of the box
    q = keys[7]["position"]
    assert dist(q, keys[8]["position"]) == pytest.approx(2 * r0 * math.sin(math.pi / 30), rel=1e-9)


def test_orbit_keys_tilted_up_radius_and_center():
    cam = {"position": [1.0, 2.0, 3.0], "look_at": [0.0, 0.0, 0.0], "up": [0.0, 0.0, 2.0], "fov_deg": 40}
    keys, _ = restir.orbit_keys(cam, 8, 24.0)
    for k in keys:
        assert k["position"][2] == pytest.approx(3.0)         # height along up kept
        assert math.hypot(k["position"][0], k["position"][1]) == pytest.approx(math.sqrt(5.0))
    keys, _ = restir.orbit_keys(cam, 8, 24.0, radius=10.0, center=[1.0, 1.0, 0.0])
    for k in keys:
        assert k["look_at"] == [1.0, 1.0, 0.0]
        assert math.hypot(k["position"][0] - 1.0, k["position"][1] - 1.0) == pytest.approx(10.0)
        assert k["position"][2] == pytest.approx(3.0)


def test_orbit_keys_more_frames_than_keys():
    keys, interp = restir.orbit_keys(CAMERA, 10000, 30.0, max_keys=100)
    assert interp == "catmull_rom" and len(keys) == 100
    assert keys[0]["t"] == 0.0 and keys[-1]["t"] == pytest.approx(9999 / 30.0)
    assert keys[0]["position"] == CAMERA["position"]


def test_orbit_keys_camera_above_center_needs_radius():
    cam = {"position": [0.0, 5.0, 0.0], "look_at": [0.0, 0.0, 0.0], "up": [0.0, 1.0, 0.0], "fov_deg": 40}
    with pytest.raises(ValueError):
        restir.orbit_keys(cam, 4, 30.0)
    keys, _ = restir.orbit_keys(cam, 4, 30.0, radius=2.0)
    assert all(dist(k["position"], [0, 5, 0]) == pytest.approx(2.0) for k in keys)


# ---- server-sent events ----

def test_parse_sse():
    text = (": keepalive\n\nevent: frame\ndata: {\"frame\": 3, \"job\": \"r1\"}\n\n"
            "event: progress\r\ndata: {\"job\": \"r1\",\r\ndata:  \"frames_done\": 4}\r\n\r\n"
            "data: plain\n\n")
    evs = list(restir.parse_sse(io.BytesIO(text.encode())))
    assert evs == [("frame", {"frame": 3, "job": "r1"}), ("progress", {"job": "r1", "frames_done": 4}),
                   ("message", "plain")]


# ---- transport, retries, recovery ----

def test_connection_failure_is_status_0():
    c = restir.Client("http://127.0.0.1:9", timeout=2, retries=0)
    with pytest.raises(restir.RestirError) as exc:
        c.health()
    assert exc.value.status == 0


def test_scene_not_loaded_reuploads_scene_and_recreates_session(fake):
    c = client_for(fake)
    c.upload_scene("box", SCENE, assets={"m.ply": b"ply\nformat ascii 1.0\n"})
    s = c.create_session("box", width=32, height=16, seed=7, params={"spp": 2})
    old = s.id
    assert s.create_body == {"width": 32, "height": 16, "seed": 7, "params": {"spp": 2}}
    fake.fail_over()                       # the proxy now sends "box" to a daemon without it
    mark = len(fake.log)
    stats = s.frame(accept="json")
    assert stats["frame"] == 0
    seq = [(m, p) for m, p, _, _ in fake.log[mark:]]
    assert seq[0] == ("POST", "/v1/scenes/box/sessions/%s/frames" % old)        # 404 scene-not-loaded
    assert seq[1] == ("PUT", "/v1/scenes/box/assets/m.ply")                     # assets first
    assert seq[2] == ("PUT", "/v1/scenes/box")
    assert seq[3] == ("POST", "/v1/scenes/box/sessions")
    assert seq[4] == ("POST", "/v1/scenes/box/sessions/%s/frames" % s.id)       # the retry
    assert len(seq) == 5 and s.id != old and s.recreated == 1
    assert fake.scenes["box"] == json.dumps(SCENE).encode()
    assert fake.assets[("box", "m.ply")] == b"ply\nformat ascii 1.0\n"
    assert json.loads(fake.log[mark + 3][3]) == s.create_body                   # same parameters
    assert any("uploading it again" in n for n in c.notes)
    # the recovered session keeps working under its new id, with no further recovery
    mark = len(fake.log)
    assert c.frame(s, accept="png") == b"IMG:image/png:1"
    assert [(m, p) for m, p, _, _ in fake.log[mark:]] == [("POST", "/v1/scenes/box/sessions/%s/frames" % s.id)]


def test_recreated_session_gets_the_changes_in_force(fake):
    c = client_for(fake)
    c.put_scene("box", SCENE)
    s = c.create_session("box")
    s.frame(camera={"position": [1, 2, 3], "fov_deg": 30}, lights={"lamp": {"position": [0, 1, 0]}})
    s.frame(camera={"fov_deg": 45}, lights={"lamp": {"transform": {"scale": 2}, "emission": [1, 1, 1]}},
            time_s=0.5)
    fake.fail_over()
    s.frame(lights={"lamp": {"emission": [2, 2, 2]}})
    frames = [json.loads(b) for m, p, _, b in fake.log if m == "POST" and p.endswith("/frames")]
    assert frames[-2] == {"lights": {"lamp": {"emission": [2, 2, 2]}}}    # the one that was refused
    assert frames[-1] == {"camera": {"position": [1, 2, 3], "fov_deg": 45}, "time_s": 0.5,
                          "lights": {"lamp": {"transform": {"scale": 2}, "emission": [2, 2, 2]}}}
    s.frame()                                  # afterwards: only the call's own changes again
    assert json.loads(fake.log[-1][3]) == {}


def test_merge_frame_change_does_not_alias_the_request():
    pos = [1.0, 2.0, 3.0]
    state = restir.merge_frame_change({}, {"camera": {"position": pos}})
    pos[0] = 99.0
    assert state == {"camera": {"position": [1.0, 2.0, 3.0]}}


def test_scene_scoped_call_without_session_reuploads(fake):
    c = client_for(fake)
    c.put_scene("box", json.dumps(SCENE))
    fake.fail_over()
    s = c.create_session("box")
    assert "box" in fake.scenes and s.create_body == {}
    assert [m for m, _, _, _ in fake.log[-3:]] == ["POST", "PUT", "POST"]


def test_recovery_retries_only_once(fake):
    c = client_for(fake)
    c.put_scene("box", SCENE)
    s = c.create_session("box")
    fake.fail_over()
    real = fake._route

    def lose_again(method, path, headers, body):
        if path.endswith("/frames"):
            return fake.problem(404, "scene-not-loaded", "gone again", path)
        return real(method, path, headers, body)
    fake._route = lose_again
    with pytest.raises(restir.RestirError) as exc:
        s.frame()
    assert exc.value.slug == "scene-not-loaded"
    assert len([1 for m, p, _, _ in fake.log if p == "/v1/scenes/box" and m == "PUT"]) == 2


def test_unknown_scene_is_not_recovered(fake):
    c = client_for(fake)
    with pytest.raises(restir.RestirError) as exc:
        c.create_session("never-uploaded")
    assert exc.value.status == 404 and exc.value.slug == "scene-not-loaded"
    assert exc.value.served_by == "fake:0" and exc.value.request_id
    assert [m for m, _, _, _ in fake.log] == ["POST"]


def test_lost_session_of_builtin_scene_is_recreated(fake):
    c = client_for(fake)
    s = c.create_session("lib-box", params={"spp": 3})
    old = s.id
    fake.fail_over()
    assert s.frame() == b"IMG:image/x-exr:0"
    seq = [(m, p) for m, p, _, _ in fake.log[1:]]
    assert seq == [("POST", "/v1/scenes/lib-box/sessions/%s/frames" % old),   # not-found
                   ("GET", "/v1/scenes/lib-box/sessions/%s" % old),           # gone? yes
                   ("POST", "/v1/scenes/lib-box/sessions"),
                   ("POST", "/v1/scenes/lib-box/sessions/%s/frames" % s.id)]


def test_missing_frame_of_live_session_is_not_recovered(fake):
    c = client_for(fake)
    s = c.create_session("lib-box")
    with pytest.raises(restir.RestirError) as exc:
        s.get_frame(5)
    assert exc.value.slug == "not-found" and s.recreated == 0


def test_busy_is_retried_after_retry_after(fake):
    c = client_for(fake)
    fake.busy[("POST", r"/v1/scenes/lib-box/sessions")] = 2
    s = c.create_session("lib-box")
    assert s.id and len(fake.calls("POST")) == 3
    fake.busy[("POST", r".*/frames")] = 10
    c.retries = 3
    with pytest.raises(restir.RestirError) as exc:
        s.frame()
    assert exc.value.status == 503 and exc.value.slug == "busy" and exc.value.retry_after == 0.0


def test_render_retry_keeps_idempotency_key(fake):
    c = client_for(fake)
    s = c.create_session("lib-box")
    fake.busy[("POST", r".*/renders")] = 1
    job = s.render({"fps": 30, "frames": 3})
    posts = [h for m, p, h, _ in fake.log if m == "POST" and p.endswith("/renders")]
    assert len(posts) == 2 and posts[0]["Idempotency-Key"] == posts[1]["Idempotency-Key"]
    assert len(fake.jobs) == 1
    done = c.wait_job(s, job, timeout=5)
    assert done["status"] == "done" and len(done["frames"]) == 3
    assert c.job_metrics(s, job, fmt="csv").startswith("frame,time_s,render_ms,mape,rmse,relmse\n")


def test_failed_job_raises_its_problem(fake):
    c = client_for(fake)
    s = c.create_session("lib-box")
    job = s.render({"frames": 1})
    fake.jobs[job["id"]].update(status="failed", error={"type": P + "internal", "title": "Internal",
                                                        "status": 500, "detail": "out of memory",
                                                        "instance": "/x"})
    with pytest.raises(restir.RestirError) as exc:
        c.wait_job(s, job, timeout=5)
    assert exc.value.slug == "internal" and exc.value.detail == "out of memory"


# ---- command line against the fake ----

def run_cli(fake, *argv):
    return run_cli_at(fake.url, *argv)


def run_cli_at(server, *argv):
    out, err = io.StringIO(), io.StringIO()
    code = restir.main(["--server", server, *argv], out=out, err=err)
    return code, out.getvalue(), err.getvalue()


def test_cli_upload_sends_assets_first_and_rewrites_mesh_paths(fake, tmp_path):
    (tmp_path / "meshes").mkdir()
    (tmp_path / "meshes" / "m.ply").write_bytes(b"PLYDATA")
    extra = tmp_path / "other.obj"
    extra.write_bytes(b"v 0 0 0\n")
    doc = dict(SCENE, shapes=[{"type": "mesh", "material": "w", "file": "meshes/m.ply"}])
    (tmp_path / "scene.json").write_text(json.dumps(doc))
    code, out, err = run_cli(fake, "upload", "up", str(tmp_path / "scene.json"), str(extra))
    assert code == 0, err
    puts = [p for m, p, _, _ in fake.log if m == "PUT"]
    assert puts == ["/v1/scenes/up/assets/other.obj", "/v1/scenes/up/assets/m.ply", "/v1/scenes/up"]
    assert json.loads(fake.scenes["up"])["shapes"][0]["file"] == "m.ply"
    assert fake.assets[("up", "m.ply")] == b"PLYDATA"
    assert "scene up: created" in err


def test_cli_frame_writes_file_and_cleans_up(fake, tmp_path):
    out_file = tmp_path / "f.exr"
    code, out, err = run_cli(fake, "frame", "lib-box", "-o", str(out_file), "--size", "8x4", "--spp", "2")
    assert code == 0, err
    assert out_file.read_bytes() == b"IMG:image/x-exr:0"
    create = [json.loads(b) for m, p, _, b in fake.log if m == "POST" and p.endswith("/sessions")][0]
    assert create == {"method": "pt", "width": 8, "height": 4, "seed": 0, "params": {"spp": 2}, "profile": "converge"}
    assert not fake.sessions                                     # deleted afterwards
    code, out, err = run_cli(fake, "frame", "lib-box", "-o", str(tmp_path / "f.png"))
    assert code == 0 and (tmp_path / "f.png").read_bytes() == b"IMG:image/png:0"


def test_cli_server_error_exit_1_prints_problem(fake, tmp_path):
    code, out, err = run_cli(fake, "frame", "missing", "-o", str(tmp_path / "x.exr"))
    assert code == 1
    assert "scene-not-loaded" in err and "this daemon does not hold scene missing" in err


def test_cli_orbit_submits_one_job_and_downloads_every_frame(fake, tmp_path):
    code, out, err = run_cli(fake, "orbit", "lib-box", "--frames", "5", "-o", str(tmp_path / "o"))
    assert code == 0, err
    files = sorted(p.name for p in (tmp_path / "o").iterdir())
    assert files == ["frame_%04d.exr" % i for i in range(5)]
    (job,) = fake.jobs.values()
    anim = job["_req"]["animation"]
    assert anim["frames"] == 5 and len(anim["camera_keys"]) == 5
    assert anim["camera_keys"][0]["position"] == CAMERA["position"]


def test_cli_orbit_names_frames_by_number_and_fails_on_evicted_ones(fake, tmp_path):
    """Polling offers only the frames still kept: each is saved under its own number, and the
    frames gone before they were fetched make the command fail with frame-evicted."""
    fake.frames_kept = 2
    code, out, err = run_cli(fake, "orbit", "lib-box", "--frames", "5", "-o", str(tmp_path / "o"))
    assert code == 1
    assert "frame-evicted" in err and "frame 0 was evicted before it was downloaded" in err, err
    assert not (tmp_path / "o").exists() or not list((tmp_path / "o").iterdir())
    fake.frames_kept = 5
    code, out, err = run_cli(fake, "orbit", "lib-box", "--frames", "5", "-o", str(tmp_path / "p"))
    assert code == 0, err
    assert sorted(p.name for p in (tmp_path / "p").iterdir()) == ["frame_%04d.exr" % i for i in range(5)]
    assert (tmp_path / "p" / "frame_0003.exr").read_bytes().endswith(b":3")
    # Frames are named by their index in the job, not by the session's frame number: a session
    # that had rendered frames before the job numbers the job's frames from there.
    fake.frames_before = 3
    code, out, err = run_cli(fake, "orbit", "lib-box", "--frames", "5", "-o", str(tmp_path / "q"))
    assert code == 0, err
    assert sorted(p.name for p in (tmp_path / "q").iterdir()) == ["frame_%04d.exr" % i for i in range(5)]
    assert (tmp_path / "q" / "frame_0000.exr").read_bytes().endswith(b":3")
    assert (tmp_path / "q" / "frame_0004.exr").read_bytes().endswith(b":7")


@pytest.mark.parametrize("method", ["pt", "sms"])
def test_cli_metrics_writes_csv(fake, tmp_path, method):
    out_file = tmp_path / "m.csv"
    code, out, err = run_cli(fake, "metrics", "lib-box", "--reference-spp", "64", "--frames", "4",
                             "--reference-method", method, "-o", str(out_file))
    assert code == 0, err
    rows = out_file.read_text().splitlines()
    assert rows[0] == "frame,time_s,render_ms,mape,rmse,relmse" and len(rows) == 5
    kinds = [j["kind"] for j in fake.jobs.values()]
    assert kinds == ["reference", "animation"]
    ref, anim = fake.jobs.values()
    assert ref["_req"] == {"spp": 64, "method": method} and anim["_req"]["reference"] == ref["reference"]
    # The reference it named after its session is deleted after the session.
    deletes = [p for m, p, _, _ in fake.log if m == "DELETE"]
    assert re.fullmatch(r"/v1/scenes/lib-box/sessions/(s\d+)", deletes[0]), deletes
    assert deletes[1:] == ["/v1/scenes/lib-box/references/ref-" + deletes[0].rsplit("/", 1)[1]]
    assert ref["reference"] == "ref-" + deletes[0].rsplit("/", 1)[1] and not fake.refs


def test_cli_metrics_keeps_a_reference_it_was_told_to_name(fake, tmp_path):
    code, _, err = run_cli(fake, "metrics", "lib-box", "--reference", "mine", "--frames", "2",
                           "-o", str(tmp_path / "m.csv"))
    assert code == 0, err
    assert fake.refs == {"mine"} and not [p for m, p, _, _ in fake.log if m == "DELETE" and "/references/" in p]


def test_cli_metrics_deletes_its_reference_when_the_job_fails(fake, tmp_path):
    fake.busy[("POST", r".*/renders$")] = 99
    code, _, err = run_cli(fake, "--timeout", "5", "metrics", "lib-box", "--frames", "2", "-o", str(tmp_path / "m.csv"))
    assert code == 1, err
    assert not fake.refs and not fake.sessions


def test_cli_metrics_cleans_up_all_and_reports_the_run_error(fake, tmp_path):
    """Deleting the session fails: the reference is deleted all the same, and the error the run
    ended with is the one reported; after a run that succeeded, the failed deletion is."""
    fake.refuse[("DELETE", r".*/sessions/[^/]+")] = (500, "internal", "the session would not go")
    fake.refuse[("GET", r".*/metrics")] = (422, "invalid-field", "no series for this job")
    code, _, err = run_cli(fake, "metrics", "lib-box", "--frames", "2", "-o", str(tmp_path / "m.csv"))
    assert code == 1 and "no series for this job" in err, err
    assert not fake.refs
    del fake.refuse[("GET", r".*/metrics")]
    code, _, err = run_cli(fake, "metrics", "lib-box", "--frames", "2", "-o", str(tmp_path / "m.csv"))
    assert code == 1 and "the session would not go" in err, err
    assert not fake.refs


@pytest.mark.parametrize("given, url", [
    ("127.0.0.1:8080", "http://127.0.0.1:8080"), ("localhost:9/", "http://localhost:9"),
    ("http://h:1", "http://h:1"), ("https://h:1/", "https://h:1"), ("[::1]:8080", "http://[::1]:8080"),
])
def test_server_without_a_scheme_is_http(given, url):
    assert restir.Client(given).server == url


def test_cli_server_without_a_scheme(fake):
    code, out, err = run_cli_at(fake.url[len("http://"):], "health")
    assert code == 0, err
    info = json.loads(out)
    assert info["ready"] == "ready" and info["served_by"] == "fake:0", out


def test_token_sent_from_argument_environment_and_token_file(fake, tmp_path, monkeypatch):
    monkeypatch.delenv("RESTIRD_AUTH_TOKEN", raising=False)
    client_for(fake).limits()
    assert "Authorization" not in fake.log[-1][2]
    client_for(fake, token="given-token-0123456789").limits()
    assert fake.log[-1][2]["Authorization"] == "Bearer given-token-0123456789"
    monkeypatch.setenv("RESTIRD_AUTH_TOKEN", "env-token-0123456789")
    client_for(fake).limits()
    assert fake.log[-1][2]["Authorization"] == "Bearer env-token-0123456789"
    f = tmp_path / "token"
    f.write_text("file-token-0123456789\n")
    code, _, err = run_cli(fake, "--token-file", str(f), "health")
    assert code == 0, err
    assert {h["Authorization"] for _, p, h, _ in fake.log[-3:]} == {"Bearer file-token-0123456789"}
    code, _, err = run_cli(fake, "--token-file", str(tmp_path / "missing"), "health")
    assert code == 2 and err.startswith("restir.py: --token-file: "), err


# ---- the package ----

def test_pip_installs_the_client_with_its_command(fake, tmp_path):
    """clients/python is a package pip installs offline (setuptools from the system, no index):
    the module, and a `restir-client` command that runs the client's main."""
    src = tmp_path / "src"
    shutil.copytree(ROOT / "clients" / "python", src, ignore=shutil.ignore_patterns("__pycache__"))
    site = tmp_path / "site"
    env = {**os.environ, "PIP_DISABLE_PIP_VERSION_CHECK": "1", "PIP_NO_INDEX": "1"}
    run = subprocess.run(["/usr/bin/python3", "-m", "pip", "install", "--no-index", "--no-build-isolation",
                          "--target", str(site), str(src)], capture_output=True, text=True, env=env, timeout=300)
    assert run.returncode == 0, run.stdout + run.stderr
    assert (site / "restir.py").read_bytes() == (ROOT / "clients" / "python" / "restir.py").read_bytes()
    (info,) = site.glob(f"restir_client-{restir.__version__}.dist-info")   # pyproject.toml reads it
    assert "restir-client = restir:main" in (info / "entry_points.txt").read_text()
    assert "Requires-Dist" not in (info / "METADATA").read_text()       # standard library only
    command = site / "bin" / "restir-client"
    run = subprocess.run([str(command), "--server", fake.url[len("http://"):], "health"], capture_output=True,
                         text=True, env={**env, "PYTHONPATH": str(site)}, timeout=60)
    assert run.returncode == 0, run.stderr
    assert json.loads(run.stdout)["served_by"] == "fake:0"
    # Its usage and messages name the command it was run as.
    bad = subprocess.run([str(command), "--no-such-option"], capture_output=True, text=True,
                         env={**env, "PYTHONPATH": str(site)}, timeout=60)
    assert bad.returncode == 2 and bad.stderr.startswith("usage: restir-client "), bad.stderr
