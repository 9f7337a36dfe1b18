#!/usr/bin/env python3
"""restir.py — a client for the restird HTTP/JSON API (protocol/API.md), as a module and a CLI.

Standard library only. As a module:

    import restir
    c = restir.Client("http://127.0.0.1:8080")
    s = c.create_session("cornell-box", width=128, height=128, params={"spp": 4})
    exr = s.frame()                               # bytes (EXR)
    stats = s.frame(accept="json")                # dict
    c.delete_session(s)

As a command-line tool:

    python3 clients/python/restir.py [--server URL] COMMAND ...

Commands: health, scenes, frame, orbit, metrics, upload (`--help` on each). Exit codes: 0 ok,
1 the server or the connection failed (the problem's detail and field are printed), 2 usage.

Scale-out: several daemons may sit behind a proxy that routes by scene. When a scene-scoped
call answers 404 `scene-not-loaded` and this client uploaded the scene (it keeps the scene
JSON and its assets in memory), it uploads them again, re-creates the session with the
parameters it was created with, and retries the call once. 429 and 503 answers are retried
after `Retry-After` (bounded).
"""
import argparse
import csv
import email.utils
import http.client
import io
import json
import math
import os
import queue
import random
import sys
import threading
import time
import urllib.error
import urllib.parse
import urllib.request
import uuid

__all__ = ["Client", "Session", "RestirError", "orbit_keys", "parse_sse", "merge_frame_change", "main"]

# The release of restird this client goes with (server/version.h's RESTIRD_VERSION; the package's
# version in pyproject.toml is read from here).
__version__ = "0.1.0"
DEFAULT_SERVER = os.environ.get("RESTIRD_URL", "http://127.0.0.1:8080")
PROBLEM_PREFIX = "urn:restird:problem:"

ACCEPT = {
    "exr": "image/x-exr",
    "png": "image/png",
    "json": "application/json",
    "csv": "text/csv",
}


class RestirError(Exception):
    """An error answer (RFC 9457 problem) or a transport failure (status 0).

    `type` is the full URN, `slug` the part after urn:restird:problem:."""

    def __init__(self, status, type=None, title=None, detail=None, field=None, limit=None,
                 instance=None, request_id=None, served_by=None, retry_after=None):
        self.status = status
        self.type = type
        self.title = title
        self.detail = detail
        self.field = field
        self.limit = limit
        self.instance = instance
        self.request_id = request_id
        self.served_by = served_by
        self.retry_after = retry_after
        super().__init__(str(self))

    @property
    def slug(self):
        if self.type and self.type.startswith(PROBLEM_PREFIX):
            return self.type[len(PROBLEM_PREFIX):]
        return self.type

    @classmethod
    def from_problem(cls, problem, status=None, headers=None):
        """Builds the error from a problem object (dict), e.g. a job's `error`."""
        problem = problem if isinstance(problem, dict) else {}
        headers = headers or {}
        st = problem.get("status") if isinstance(problem.get("status"), int) else status
        return cls(st if st is not None else 0,
                   type=problem.get("type"), title=problem.get("title"),
                   detail=problem.get("detail"), field=problem.get("field"),
                   limit=problem.get("limit"), instance=problem.get("instance"),
                   request_id=headers.get("X-Request-Id"), served_by=headers.get("X-Served-By"),
                   retry_after=parse_retry_after(headers.get("Retry-After")))

    @classmethod
    def from_response(cls, status, headers, body):
        """Parses an error answer; a body that is not a problem object still gives an error
        carrying the status (and the start of the text as detail)."""
        problem = None
        if body:
            try:
                problem = json.loads(body.decode("utf-8"))
            except (ValueError, UnicodeDecodeError):
                problem = None
        if not isinstance(problem, dict):
            text = body.decode("utf-8", "replace").strip()[:200] if body else ""
            problem = {"detail": text or None}
        problem = dict(problem)
        problem["status"] = status  # the HTTP status is authoritative
        return cls.from_problem(problem, status, headers)

    def __str__(self):
        head = str(self.status) if self.status else "error"
        if self.slug:
            head += " " + self.slug
        text = head + (": " + self.detail if self.detail else "")
        if self.field is not None:
            text += " (field %s)" % (json.dumps(self.field) if self.field == "" else self.field)
        if self.limit is not None:
            text += " (limit %s)" % fmt_num(self.limit)
        return text


def fmt_num(x):
    return str(int(x)) if isinstance(x, float) and x.is_integer() else str(x)


def parse_retry_after(value):
    """Retry-After as seconds (delta-seconds or an HTTP date); None when absent or bad."""
    if value is None:
        return None
    value = str(value).strip()
    try:
        return max(0.0, float(int(value)))
    except ValueError:
        pass
    try:
        when = email.utils.parsedate_to_datetime(value)
    except (TypeError, ValueError, IndexError):
        return None
    if when is None:
        return None
    return max(0.0, when.timestamp() - time.time())


class Response:
    """An answer: status, headers (case-insensitive get) and body bytes."""

    def __init__(self, status, headers, body):
        self.status = status
        self.headers = headers
        self.body = body

    def json(self):
        return json.loads(self.body.decode("utf-8")) if self.body else None

    @property
    def content_type(self):
        return (self.headers.get("Content-Type") or "").split(";")[0].strip().lower()


class _NoRedirect(urllib.request.HTTPRedirectHandler):
    """Redirects are followed by the client itself (so the retry logic sees every answer)."""

    def redirect_request(self, req, fp, code, msg, headers, newurl):
        return None


def server_url(server):
    """The daemon's base URL: `host:port` without a scheme is taken as http://host:port."""
    server = server.strip().rstrip("/")
    if "://" not in server:
        server = "http://" + server
    return server


def _q(segment):
    return urllib.parse.quote(str(segment), safe="")


class Session:
    """A session created through a Client. It keeps the parameters it was created with, so the
    client can re-create it transparently when its daemon no longer holds the scene.

    `id` may change after such a recovery; `info` is the last session object the server sent."""

    def __init__(self, client, scene, create_body, info):
        self.client = client
        self.scene = scene
        self.create_body = dict(create_body)
        self.info = info
        self.id = info["id"]
        self.deleted = False
        self.recreated = 0
        self.known = True    # created through this client: it can be re-created
        # The camera, shape and time changes sent with frames so far (they stay in force on the
        # server); replayed with the first frame after a re-creation.
        self.state = {}

    def remember(self, change):
        """Folds one frame request's changes into `state`."""
        merge_frame_change(self.state, change)

    @property
    def path(self):
        return "/v1/scenes/%s/sessions/%s" % (_q(self.scene), _q(self.id))

    @property
    def camera(self):
        return self.info.get("camera")

    def __repr__(self):
        return "Session(%r, %r)" % (self.scene, self.id)

    # Shortcuts to the client's session-scoped calls.
    def frame(self, **kw):
        return self.client.frame(self, **kw)

    def get_frame(self, n="latest", **kw):
        return self.client.get_frame(self, n, **kw)

    def frame_metrics(self, n, reference):
        return self.client.frame_metrics(self, n, reference)

    def render(self, animation, **kw):
        return self.client.render(self, animation, **kw)

    def reset(self):
        return self.client.reset_session(self)

    def delete(self, missing_ok=False):
        return self.client.delete_session(self, missing_ok=missing_ok)

    def refresh(self):
        return self.client.get_session(self)


class Client:
    """A restird client. One instance may be shared by threads only for independent calls."""

    def __init__(self, server=DEFAULT_SERVER, timeout=600.0, retries=5, max_retry_wait=30.0,
                 retry_budget=120.0, recover=True, log=None, token=None):
        self.server = server_url(server)
        # The daemon's bearer token (its --auth-token-file or RESTIRD_AUTH_TOKEN), sent with
        # every call when given; by default the same environment variable the daemon reads.
        self.token = token if token is not None else os.environ.get("RESTIRD_AUTH_TOKEN") or None
        self.timeout = timeout
        self.retries = retries                  # 429/503 retries per call
        self.max_retry_wait = max_retry_wait    # cap on one Retry-After sleep
        self.retry_budget = retry_budget        # cap on all sleeps of one call
        self.recover = recover                  # re-upload/re-create on scene-not-loaded
        self.log = log                          # callable(str) for progress notes, or None
        self.last_response = None
        self._sources = {}   # scene -> {"doc": bytes, "assets": {name: (bytes, content_type)}}
        self._sessions = {}  # (scene, sid) -> Session
        self._jobs = {}      # job id -> Location path
        self._methods = None  # GET /v1/methods, by name, once fetched
        self._opener = urllib.request.build_opener(_NoRedirect)

    # ---- transport ----

    def _note(self, text):
        if self.log:
            self.log(text)

    def _url(self, path, query=None):
        if path.startswith("http://") or path.startswith("https://"):
            url = path
        else:
            url = self.server + path
        if query:
            items = [(k, _qval(v)) for k, v in query.items() if v is not None]
            if items:
                url += ("&" if "?" in url else "?") + urllib.parse.urlencode(items)
        return url

    def _send_once(self, method, url, body, headers, timeout):
        req = urllib.request.Request(url, data=body, method=method, headers=headers)
        try:
            try:
                resp = self._opener.open(req, timeout=timeout)
            except urllib.error.HTTPError as e:
                data = e.read() if e.fp is not None else b""
                return Response(e.code, e.headers, data)
            with resp:
                return Response(resp.status, resp.headers, resp.read())
        except urllib.error.URLError as e:
            raise RestirError(0, detail="cannot reach %s: %s" % (self.server, e.reason)) from None
        except (OSError, http.client.HTTPException) as e:
            raise RestirError(0, detail="connection to %s failed: %s" % (self.server, e)) from None

    def request(self, method, path, *, json_body=None, body=None, content_type=None, accept=None,
                query=None, headers=None, ok=(200, 201, 202, 204), stream=False, timeout=None):
        """One call with 429/503 retries and 303 following; returns a Response or raises
        RestirError. `path` is a server path (or a full URL)."""
        hdrs = {"User-Agent": "restir.py/1"}
        if json_body is not None:
            body = json.dumps(json_body, allow_nan=False).encode("utf-8")
            content_type = content_type or "application/json"
        if body is not None:
            hdrs["Content-Type"] = content_type or "application/octet-stream"
        elif method in ("POST", "PUT"):
            body = b""   # Content-Length: 0; an empty body is the same as {}
            hdrs["Content-Type"] = "application/json"
        if accept:
            hdrs["Accept"] = ACCEPT.get(accept, accept)
        if self.token:
            hdrs["Authorization"] = "Bearer " + self.token
        hdrs.update(headers or {})
        url = self._url(path, query)
        if stream:
            return self._open_stream(method, url, hdrs, timeout)
        slept = 0.0
        attempt = 0
        redirects = 0
        while True:
            resp = self._send_once(method, url, body, hdrs, timeout or self.timeout)
            self.last_response = resp
            if resp.status == 303 and redirects < 5 and resp.headers.get("Location"):
                url = urllib.parse.urljoin(url, resp.headers["Location"])
                method, body = "GET", None
                hdrs.pop("Content-Type", None)
                redirects += 1
                continue
            if resp.status in ok:
                return resp
            if resp.status in (429, 503) and attempt < self.retries:
                wait = parse_retry_after(resp.headers.get("Retry-After"))
                if wait is None:
                    wait = min(2.0 ** attempt, self.max_retry_wait)
                # a little jitter, so clients that were turned away together do not return together
                wait = min(wait * (1.0 + 0.2 * random.random()), self.max_retry_wait)
                if slept + wait <= self.retry_budget:
                    err = RestirError.from_response(resp.status, resp.headers, resp.body)
                    self._note("%s; retrying in %.3g s" % (err, wait))
                    time.sleep(wait)
                    slept += wait
                    attempt += 1
                    continue
            raise RestirError.from_response(resp.status, resp.headers, resp.body)

    def _open_stream(self, method, url, hdrs, timeout):
        req = urllib.request.Request(url, method=method, headers=hdrs)
        try:
            return self._opener.open(req, timeout=timeout)
        except urllib.error.HTTPError as e:
            data = e.read() if e.fp is not None else b""
            raise RestirError.from_response(e.code, e.headers, data) from None
        except urllib.error.URLError as e:
            raise RestirError(0, detail="cannot reach %s: %s" % (self.server, e.reason)) from None

    # ---- scale-out recovery ----

    def _session(self, session, scene=None):
        """A Session from a Session or a session id (known to this client, or a bare one)."""
        if isinstance(session, Session):
            return session
        if scene is not None and (scene, session) in self._sessions:
            return self._sessions[(scene, session)]
        for (sc, sid), s in self._sessions.items():
            if sid == session and (scene is None or sc == scene):
                return s
        if scene is None:
            raise ValueError("session %r is not known to this client: pass scene=" % (session,))
        s = Session(self, scene, {}, {"id": session})
        s.known = False
        return s

    def _has_source(self, scene):
        return bool(self._sources.get(scene, {}).get("doc"))

    def _reupload(self, scene):
        src = self._sources[scene]
        self._note("scene %s is not loaded on this daemon: uploading it again" % scene)
        for name, (data, ctype) in src["assets"].items():
            self.request("PUT", "/v1/scenes/%s/assets/%s" % (_q(scene), _q(name)), body=data,
                         content_type=ctype)
        self.request("PUT", "/v1/scenes/%s" % _q(scene), body=src["doc"],
                     content_type="application/json")

    def _recreate(self, s):
        self._note("re-creating session %s of %s" % (s.id, s.scene))
        resp = self.request("POST", "/v1/scenes/%s/sessions" % _q(s.scene), json_body=s.create_body)
        info = resp.json()
        self._sessions.pop((s.scene, s.id), None)
        s.info, s.id = info, info["id"]
        s.recreated += 1
        self._sessions[(s.scene, s.id)] = s

    def _session_lost(self, s):
        try:
            self.request("GET", s.path)
        except RestirError as e:
            return e.status == 404
        return False

    def _scoped(self, scene, call, session=None):
        """Runs call() and recovers once from a daemon that lost the scene or the session:
        - 404 scene-not-loaded for a scene this client uploaded: uploads its assets and JSON
          again, re-creates `session` (if any) with its creation parameters, runs call() again
          (frame() then also replays the camera and shape changes in force);
        - 404 not-found for a session this client created (and did not delete), when the
          session itself is gone (e.g. a built-in scene's session after a fail-over to another
          daemon): re-creates the session and runs call() again.
        call must build its path from session.id when it runs: re-creation changes the id."""
        try:
            return call()
        except RestirError as e:
            if not self.recover or e.status != 404:
                raise
            usable = session is None or (session.known and not session.deleted)
            if e.slug == "scene-not-loaded" and self._has_source(scene) and usable:
                self._reupload(scene)
                if session is not None:
                    self._recreate(session)
                return call()
            if e.slug == "not-found" and session is not None and usable and self._session_lost(session):
                self._recreate(session)
                return call()
            raise

    # ---- service ----

    def health(self):
        return self.request("GET", "/healthz").json()

    def ready(self):
        return self.request("GET", "/readyz").json()

    def limits(self):
        return self.request("GET", "/v1/limits").json()

    def methods(self):
        """The daemon's method registry, by name: each method's summary, capabilities and
        parameters (name, type, default, range, help), as GET /v1/methods gives it."""
        if self._methods is None:
            self._methods = {m["name"]: m for m in self.request("GET", "/v1/methods").json()["methods"]}
        return self._methods

    def openapi(self):
        return self.request("GET", "/v1/openapi.yaml").body.decode("utf-8")

    def prometheus(self):
        return self.request("GET", "/metrics").body.decode("utf-8")

    # ---- scenes ----

    def scenes(self):
        return self.request("GET", "/v1/scenes").json()["scenes"]

    def get_scene(self, scene):
        return self._scoped(scene, lambda: self.request("GET", "/v1/scenes/%s" % _q(scene)).json())

    def put_scene(self, scene, doc):
        """Uploads a scene (dict, str or bytes of JSON); remembered for re-uploads. Returns the
        scene object, with "created": True on 201."""
        data = doc if isinstance(doc, bytes) else (
            doc.encode("utf-8") if isinstance(doc, str) else json.dumps(doc).encode("utf-8"))
        resp = self.request("PUT", "/v1/scenes/%s" % _q(scene), body=data,
                            content_type="application/json")
        src = self._sources.setdefault(scene, {"doc": None, "assets": {}})
        src["doc"] = data
        out = resp.json() or {}
        if isinstance(out, dict):
            out.setdefault("created", resp.status == 201)
        return out

    def put_asset(self, scene, name, data, content_type="application/octet-stream"):
        """Uploads a mesh file (bytes); remembered for re-uploads. Returns True when created."""
        resp = self.request("PUT", "/v1/scenes/%s/assets/%s" % (_q(scene), _q(name)), body=data,
                            content_type=content_type)
        src = self._sources.setdefault(scene, {"doc": None, "assets": {}})
        src["assets"][name] = (bytes(data), content_type)
        return resp.status == 201

    def upload_scene(self, scene, doc, assets=None):
        """Uploads the assets ({name: bytes}) and then the scene."""
        for name, data in (assets or {}).items():
            self.put_asset(scene, name, data)
        return self.put_scene(scene, doc)

    def delete_scene(self, scene, force=False):
        self.request("DELETE", "/v1/scenes/%s" % _q(scene), query={"force": True if force else None})
        self._sources.pop(scene, None)
        for key in [k for k in self._sessions if k[0] == scene]:
            self._sessions.pop(key).deleted = True

    def forget_scene(self, scene):
        """Stops re-uploading a scene on scene-not-loaded."""
        self._sources.pop(scene, None)

    # ---- references (scene level) ----

    def put_reference(self, scene, name, exr, content_type="image/x-exr"):
        path = "/v1/scenes/%s/references/%s" % (_q(scene), _q(name))
        return self._scoped(scene, lambda: self.request("PUT", path, body=exr, content_type=content_type)).status

    def get_reference(self, scene, name, accept="exr", **query):
        path = "/v1/scenes/%s/references/%s" % (_q(scene), _q(name))
        resp = self._scoped(scene, lambda: self.request("GET", path, accept=accept, query=query))
        return _body(resp)

    def references(self, scene):
        """The scene's references: [{"name", "width", "height", "spp", "method", "bytes", "created", "href"}]."""
        path = "/v1/scenes/%s/references" % _q(scene)
        return self._scoped(scene, lambda: self.request("GET", path)).json()["references"]

    def delete_reference(self, scene, name, missing_ok=False):
        path = "/v1/scenes/%s/references/%s" % (_q(scene), _q(name))
        try:
            self.request("DELETE", path)
        except RestirError as e:
            if not (missing_ok and e.status == 404):
                raise

    # ---- sessions ----

    def create_session(self, scene, method=None, width=None, height=None, seed=None, params=None, profile=None):
        """profile: "real_time" (the daemon's default when None) or "converge" (protocol/API.md,
        Sessions): the defaults `params` is read over."""
        body = {}
        for key, value in (("method", method), ("width", width), ("height", height), ("seed", seed),
                           ("profile", profile), ("params", params)):
            if value is not None:
                body[key] = value
        path = "/v1/scenes/%s/sessions" % _q(scene)
        info = self._scoped(scene, lambda: self.request("POST", path, json_body=body).json())
        s = Session(self, scene, body, info)
        self._sessions[(scene, s.id)] = s
        return s

    def list_sessions(self, scene):
        path = "/v1/scenes/%s/sessions" % _q(scene)
        return self._scoped(scene, lambda: self.request("GET", path).json()["sessions"])

    def _session_call(self, session, method, suffix="", scene=None, **kw):
        s = self._session(session, scene)
        resp = self._scoped(s.scene, lambda: self.request(method, s.path + suffix, **kw), s)
        return s, resp

    def get_session(self, session, scene=None):
        s, resp = self._session_call(session, "GET", scene=scene)
        s.info = resp.json()
        return s.info

    def delete_session(self, session, scene=None, missing_ok=False):
        s = self._session(session, scene)
        try:
            self.request("DELETE", s.path)
        except RestirError as e:
            if not (missing_ok and e.status == 404):
                raise
        s.deleted = True
        self._sessions.pop((s.scene, s.id), None)

    def reset_session(self, session, scene=None):
        self._session_call(session, "POST", "/reset", scene=scene)

    # ---- frames ----

    def frame(self, session, camera=None, lights=None, time_s=None, accept="exr", pixel=None,
              exposure=None, tonemap=None, reference=None, scene=None, compression=None):
        """Renders the next frame. Returns bytes (EXR/PNG) or a dict (accept="json"); EXR as
        pixel="float"|"half" and compression="none"|"zip"|"piz" (the daemon's defaults: float, none).
        The answer's headers (X-Frame, X-Render-Ms, ETag, ...) are in client.last_response."""
        body = {}
        if camera is not None:
            body["camera"] = camera
        if lights is not None:
            body["lights"] = lights
        if time_s is not None:
            body["time_s"] = time_s
        query = {"pixel": pixel, "compression": compression, "exposure": exposure, "tonemap": tonemap,
                 "reference": reference}
        s = self._session(session, scene)
        generation = s.recreated

        def call():
            send = body
            if s.recreated != generation:   # a new session: replay the changes in force
                send = merge_frame_change(json.loads(json.dumps(s.state)), body)
            return self.request("POST", s.path + "/frames", json_body=send, accept=accept, query=query)
        resp = self._scoped(s.scene, call, s)
        s.remember(body)
        return _body(resp)

    def get_frame(self, session, n="latest", accept="exr", pixel=None, exposure=None, tonemap=None,
                  reference=None, scene=None, compression=None):
        """A kept frame (n = number or "latest"): bytes or dict as for frame()."""
        query = {"pixel": pixel, "compression": compression, "exposure": exposure, "tonemap": tonemap,
                 "reference": reference}
        _, resp = self._session_call(session, "GET", "/frames/%s" % _q(n), scene=scene,
                                     accept=accept, query=query)
        return _body(resp)

    def frame_metrics(self, session, n, reference, scene=None):
        _, resp = self._session_call(session, "GET", "/frames/%s/metrics" % _q(n), scene=scene,
                                     query={"reference": reference})
        return resp.json()

    def error_map(self, session, n, reference, scale=None, scene=None):
        _, resp = self._session_call(session, "GET", "/frames/%s/error.png" % _q(n), scene=scene,
                                     query={"reference": reference, "scale": scale})
        return resp.body

    def accumulation(self, session, accept="exr", scene=None, **query):
        _, resp = self._session_call(session, "GET", "/accumulation", scene=scene, accept=accept,
                                     query=query)
        return _body(resp)

    def frame_by_href(self, href, accept="exr", **query):
        """A frame by the href a job or an event named (no recovery: frames die with a daemon)."""
        return _body(self.request("GET", href, accept=accept, query=query))

    # ---- jobs ----

    def render(self, session, animation, reference=None, idempotency_key=None, scene=None):
        """Queues an animation job; returns the job object. A retried POST (429/503) carries the
        same Idempotency-Key, so it never creates two jobs."""
        body = {"animation": animation}
        if reference is not None:
            body["reference"] = reference
        key = idempotency_key or uuid.uuid4().hex
        s, resp = self._session_call(session, "POST", "/renders", scene=scene, json_body=body,
                                     headers={"Idempotency-Key": key})
        return self._job_answer(s, resp)

    def create_reference(self, session, name, spp=None, scene=None, method=None, idempotency_key=None):
        """Renders a reference of the session's view on the server (method "pt", the default, or
        "sms": specular manifold sampling for the caustics); returns the job object. Retries
        carry the same Idempotency-Key, so they never start a second render."""
        body = {} if spp is None else {"spp": spp}
        if method is not None:
            body["method"] = method
        key = idempotency_key or uuid.uuid4().hex
        s, resp = self._session_call(session, "POST", "/references/%s" % _q(name), scene=scene,
                                     json_body=body, headers={"Idempotency-Key": key})
        return self._job_answer(s, resp)

    def jobs(self, session, scene=None):
        """The session's jobs (animation and reference), oldest first."""
        s, resp = self._session_call(session, "GET", "/renders", scene=scene)
        return resp.json()["renders"]

    def _job_answer(self, s, resp):
        job = resp.json() or {}
        loc = resp.headers.get("Location")
        if job.get("id"):
            self._jobs[job["id"]] = urllib.parse.urlsplit(loc).path if loc else s.path + "/renders/" + _q(job["id"])
        return job

    def _job_path(self, session, job, scene=None):
        rid = job["id"] if isinstance(job, dict) else job
        if rid in self._jobs:
            return self._jobs[rid]
        return self._session(session, scene).path + "/renders/" + _q(rid)

    def job(self, session, job, scene=None):
        return self.request("GET", self._job_path(session, job, scene)).json()

    def cancel(self, session, job, scene=None):
        resp = self.request("DELETE", self._job_path(session, job, scene))
        return resp.json() if resp.body else None

    def wait_job(self, session, job, timeout=3600.0, poll=0.25, progress=None, scene=None):
        """Polls until the job is done, cancelled or failed; returns the final job object.
        progress(job) is called after each poll. A failed job raises RestirError with the job's
        problem; a timeout (seconds; None = none) raises TimeoutError."""
        deadline = time.monotonic() + (math.inf if timeout is None else timeout)
        delay = poll
        while True:
            state = self.job(session, job, scene)
            if progress:
                progress(state)
            status = state.get("status")
            if status == "failed":
                raise RestirError.from_problem(state.get("error") or {"detail": "job failed"}, 500)
            if status in ("done", "cancelled"):
                return state
            if time.monotonic() >= deadline:
                raise TimeoutError("job %s still %s after %g s" % (state.get("id"), status, timeout))
            time.sleep(min(delay, max(0.0, deadline - time.monotonic())))
            delay = min(delay * 1.5, 2.0)

    def job_metrics(self, session, job, fmt="json", reference=None, scene=None):
        """The job's per-frame series: a list of dicts (fmt="json") or the CSV text (fmt="csv")."""
        resp = self.request("GET", self._job_path(session, job, scene) + "/metrics", accept=fmt,
                            query={"reference": reference})
        if fmt == "csv":
            return resp.body.decode("utf-8")
        data = resp.json()
        if isinstance(data, dict) and isinstance(data.get("series"), list):
            return data["series"]   # tolerate a wrapped series {"reference", "series": [...]}
        return data

    # ---- events ----

    def events(self, session, scene=None, timeout=60.0):
        """Yields (event, data) from the session's event stream; data is the parsed JSON (or the
        raw text). Ends when the server closes the stream. `timeout` bounds the silence between
        two lines (the server sends a keepalive every 15 s)."""
        stream = self.open_events(session, scene, timeout)
        with stream:
            yield from parse_sse(stream)

    def open_events(self, session, scene=None, timeout=60.0):
        """The raw event stream (a file-like object of lines); parse it with parse_sse()."""
        s = self._session(session, scene)
        return self._scoped(s.scene, lambda: self.request(
            "GET", s.path + "/events", accept="text/event-stream", stream=True, timeout=timeout), s)


def merge_frame_change(state, change):
    """Folds a frame request body into `state` (the changes in force) and returns state:
    camera members and shape channels replace earlier ones; a shape's `position` and
    `transform` replace each other."""
    change = json.loads(json.dumps(change))   # a copy: state must not share the caller's lists
    if "camera" in change:
        state.setdefault("camera", {}).update(change["camera"])
    for name, ch in (change.get("lights") or {}).items():
        cur = state.setdefault("lights", {}).setdefault(name, {})
        if "position" in ch:
            cur.pop("transform", None)
        if "transform" in ch:
            cur.pop("position", None)
        cur.update(ch)
    if "time_s" in change:
        state["time_s"] = change["time_s"]
    return state


def _qval(v):
    if isinstance(v, bool):
        return "true" if v else "false"
    return str(v)


def _body(resp):
    if resp.content_type in ("application/json", "application/problem+json"):
        return resp.json()
    return resp.body


def parse_sse(lines):
    """Parses a text/event-stream from an iterable of byte (or str) lines into (event, data)."""
    event, data = None, []
    for raw in lines:
        line = raw.decode("utf-8", "replace") if isinstance(raw, bytes) else raw
        line = line.rstrip("\r\n")
        if line == "":
            if data:
                text = "\n".join(data)
                try:
                    value = json.loads(text)
                except ValueError:
                    value = text
                yield (event or "message", value)
            event, data = None, []
            continue
        if line.startswith(":"):
            continue
        name, _, value = line.partition(":")
        if value.startswith(" "):
            value = value[1:]
        if name == "event":
            event = value
        elif name == "data":
            data.append(value)


# ---- orbit keys ----

def _sub(a, b):
    return [a[0] - b[0], a[1] - b[1], a[2] - b[2]]


def _dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _cross(a, b):
    return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]


def _norm(a):
    n = math.sqrt(_dot(a, a))
    if n == 0.0 or not math.isfinite(n):
        raise ValueError("zero-length vector")
    return [a[0] / n, a[1] / n, a[2] / n]


def orbit_keys(camera, frames, fps=30.0, radius=None, center=None, turns=1.0, max_keys=4096):
    """Camera keys that orbit camera["position"] around `center` (default the camera's look_at)
    in the plane perpendicular to the camera's `up` (the horizontal plane), keeping the height
    along `up`. radius defaults to the camera's horizontal distance from the centre. Every key
    looks at the centre. With the defaults the first key is the camera itself.

    Returns (keys, interpolation): one key per frame (linear) when frames <= max_keys, otherwise
    max_keys keys spread over the animation (catmull_rom)."""
    if frames < 1:
        raise ValueError("frames must be >= 1")
    if not fps > 0:
        raise ValueError("fps must be > 0")
    pos = [float(x) for x in camera["position"]]
    c = [float(x) for x in (center if center is not None else camera["look_at"])]
    up = _norm([float(x) for x in camera.get("up", [0, 1, 0])])
    off = _sub(pos, c)
    h = _dot(off, up)
    horiz = [off[i] - h * up[i] for i in range(3)]
    hlen = math.sqrt(_dot(horiz, horiz))
    if hlen > 1e-9 * max(1.0, math.sqrt(_dot(off, off))):
        e1 = [x / hlen for x in horiz]
    else:  # camera straight above/below the centre: any horizontal direction
        trial = [1.0, 0.0, 0.0] if abs(up[0]) < 0.9 else [0.0, 0.0, 1.0]
        e1 = _norm(_cross(_cross(up, trial), up))
    e2 = _cross(up, e1)
    r = hlen if radius is None else float(radius)
    if not (r > 0 and math.isfinite(r)):
        raise ValueError("the orbit radius must be > 0 (give --radius)")
    if frames <= max_keys:
        steps, interp = list(range(frames)), "linear"
    else:
        count = max(2, max_keys)
        steps = [i * (frames - 1) / (count - 1) for i in range(count)]
        interp = "catmull_rom"
    base = [c[i] + h * up[i] for i in range(3)]
    keys = []
    for k, step in enumerate(steps):
        angle = 2.0 * math.pi * turns * step / frames
        ca, sa = math.cos(angle), math.sin(angle)
        p = [base[i] + r * (ca * e1[i] + sa * e2[i]) for i in range(3)]
        if k == 0 and radius is None:
            p = list(pos)  # exactly the scene camera
        keys.append({"t": step / fps, "position": p, "look_at": list(c)})
    return keys, interp


# ---- command line ----

class UsageError(Exception):
    pass


def parse_size(text):
    try:
        w, h = text.lower().split("x")
        w, h = int(w), int(h)
    except ValueError:
        raise argparse.ArgumentTypeError("expected WxH, e.g. 256x256, got %r" % text) from None
    if w < 1 or h < 1:
        raise argparse.ArgumentTypeError("width and height must be >= 1")
    return w, h


def parse_vec3(text):
    try:
        parts = [float(x) for x in text.split(",")]
    except ValueError:
        parts = []
    if len(parts) != 3 or not all(math.isfinite(x) for x in parts):
        raise argparse.ArgumentTypeError("expected x,y,z, got %r" % text)
    return parts


def positive_int(text):
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError("expected an integer, got %r" % text) from None
    if v < 1:
        raise argparse.ArgumentTypeError("must be >= 1")
    return v


def finite_float(text):
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError("expected a number, got %r" % text) from None
    if not math.isfinite(v):
        raise argparse.ArgumentTypeError("must be finite")
    return v


# The command line's profile names, and the protocol's.
PROFILES = {"real-time": "real_time", "converge": "converge"}


def _session_args(p, spp_default, profile_default=None):
    p.add_argument("--method", default="pt", help="rendering method (default pt)")
    p.add_argument("--size", type=parse_size, default=(256, 256), metavar="WxH",
                   help="image size (default 256x256)")
    p.add_argument("--spp", type=positive_int, default=None,
                   help="samples per pixel per frame, for the methods that take spp (GET /v1/methods: "
                        "capabilities.takes_spp; default %d); the others trace one path per pixel and "
                        "frame" % spp_default)
    p.set_defaults(spp_default=spp_default)
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    # Spelled as restir render's --profile; the daemon's names are real_time and converge.
    p.add_argument("--profile", choices=sorted(PROFILES), default=None,
                   help="the session's profile: real-time or converge (the methods that reuse frames "
                        "start from defaults that make their frames independent, for a still image; "
                        "default %s)" % (profile_default or "the daemon's, real-time"))
    p.set_defaults(profile_default=profile_default)


def _image_args(p):
    p.add_argument("--png", action="store_true", help="download an 8-bit PNG preview instead of EXR")
    p.add_argument("--exposure", type=finite_float, default=None, help="PNG exposure in EV")
    p.add_argument("--tonemap", choices=["clamp", "reinhard", "aces"], default=None, help="PNG tone curve")
    p.add_argument("--half", action="store_true", help="EXR with half-float pixels")


def build_parser():
    p = argparse.ArgumentParser(
        prog=prog_name(), description="Client for the restird render server (protocol/API.md).")
    p.add_argument("--server", default=DEFAULT_SERVER,
                   help="daemon or proxy URL; host:port alone means http:// (default $RESTIRD_URL or "
                        "http://127.0.0.1:8080)")
    p.add_argument("--timeout", type=finite_float, default=600.0,
                   help="seconds to wait for one answer (default 600)")
    p.add_argument("--token-file", default=None,
                   help="file holding the daemon's bearer token (default $RESTIRD_AUTH_TOKEN, if set)")
    p.add_argument("--wait", type=finite_float, default=None,
                   help="seconds to wait for a background job (default: no limit)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress on stderr")
    sub = p.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True

    sub.add_parser("health", help="liveness, readiness and limits of the daemon")

    sp = sub.add_parser("scenes", help="list the scenes the daemon holds")
    sp.add_argument("--json", action="store_true", help="print the JSON answer")

    sp = sub.add_parser("frame", help="render one frame of a scene to a file")
    sp.add_argument("scene")
    sp.add_argument("-o", "--output", required=True, help="output file (.exr, or .png with --png)")
    # One frame of a fresh session is a still image: the converge profile's, unless told otherwise.
    _session_args(sp, 4, "converge")
    _image_args(sp)
    sp.add_argument("--json", action="store_true", help="print the frame's stats as JSON on stdout")

    sp = sub.add_parser("orbit", help="render an orbit of the scene camera as one animation job")
    sp.add_argument("scene")
    sp.add_argument("--frames", type=positive_int, default=30, help="frames (default 30)")
    sp.add_argument("--fps", type=finite_float, default=30.0, help="frames per second (default 30)")
    sp.add_argument("-o", "--output", required=True, help="output folder (frame_0000.exr, ...)")
    sp.add_argument("--radius", type=finite_float, default=None,
                    help="orbit radius (default: the camera's horizontal distance from the centre)")
    sp.add_argument("--center", type=parse_vec3, default=None, metavar="X,Y,Z",
                    help="orbit centre and look-at point (default: the camera's look_at)")
    sp.add_argument("--turns", type=finite_float, default=1.0, help="revolutions (default 1)")
    _session_args(sp, 4)
    _image_args(sp)

    sp = sub.add_parser("metrics", help="error of a method against a server-rendered reference, as CSV")
    sp.add_argument("scene")
    sp.add_argument("--reference-spp", type=positive_int, default=1024,
                    help="samples per pixel of the reference (default 1024)")
    sp.add_argument("--reference-method", choices=("pt", "sms"), default="pt",
                    help="how the server estimates the reference: pt, or sms for the caustics of "
                         "scenes with caustic casters (default pt)")
    sp.add_argument("--reference", default=None,
                    help="reference name, kept when done (default: ref-<session id>, deleted when done)")
    sp.add_argument("--frames", type=positive_int, default=16, help="frames (default 16)")
    sp.add_argument("--fps", type=finite_float, default=30.0, help="frames per second (default 30)")
    sp.add_argument("-o", "--output", required=True, help="CSV file (- = stdout)")
    _session_args(sp, 1)

    sp = sub.add_parser("upload", help="upload a scene and its mesh assets")
    sp.add_argument("scene_id")
    sp.add_argument("scene_json")
    sp.add_argument("assets", nargs="*", help="PLY/OBJ files (uploaded under their file names)")
    return p


class Progress:
    """Progress lines on stderr: rewritten in place on a terminal, one per update otherwise."""

    def __init__(self, quiet=False, stream=None):
        self.quiet = quiet
        self.stream = stream or sys.stderr
        self.tty = hasattr(self.stream, "isatty") and self.stream.isatty()
        self._open = False

    def update(self, text):
        if self.quiet:
            return
        if self.tty:
            self.stream.write("\r\033[K" + text)
            self._open = True
        else:
            self.stream.write(text + "\n")
        self.stream.flush()

    def line(self, text):
        if self.quiet:
            return
        if self._open:
            self.stream.write("\n")
            self._open = False
        self.stream.write(text + "\n")
        self.stream.flush()


def _image_query(args):
    if args.png or (args.command == "frame" and args.output.lower().endswith(".png")):
        return "png", {"exposure": args.exposure, "tonemap": args.tonemap}
    return "exr", {"pixel": "half" if args.half else None}


def _write(path, data):
    tmp = path + ".part"
    with open(tmp, "wb") as f:
        f.write(data)
    os.replace(tmp, path)


def _session_params(args, methods):
    """The session's params: --spp as given (the daemon names it if the method refuses it), else
    the command's default for the methods whose registry entry says they take spp, else none
    (the method's defaults). `methods`: the registry by name (Client.methods()), or a callable
    that returns it, called only when --spp is not given."""
    if args.spp is not None:
        return {"spp": args.spp}
    if callable(methods):
        methods = methods()
    method = methods.get(args.method)
    takes_spp = bool(method and method.get("capabilities", {}).get("takes_spp"))
    return {"spp": args.spp_default} if takes_spp else {}


def _make_session(client, args):
    w, h = args.size
    return client.create_session(args.scene, method=args.method, width=w, height=h, seed=args.seed,
                                 params=_session_params(args, client.methods),
                                 profile=PROFILES.get(args.profile or args.profile_default))


def cmd_health(client, args, out, prog):
    health = client.health()
    served = client.last_response.headers.get("X-Served-By")
    try:
        ready = client.ready().get("status")
    except RestirError as e:
        ready = e.slug or str(e.status)
    info = {"status": health.get("status"), "ready": ready, "served_by": served,
            "limits": client.limits()}
    out.write(json.dumps(info, indent=2) + "\n")
    return 0


def cmd_scenes(client, args, out, prog):
    scenes = client.scenes()
    if args.json:
        out.write(json.dumps(scenes, indent=2) + "\n")
        return 0
    cols = ["id", "builtin", "shapes", "triangles", "emitters", "sessions", "hash"]
    def cell(v):
        return ("yes" if v else "no") if isinstance(v, bool) else str(v)
    rows = [[cell(s.get(c, "")) for c in cols] for s in scenes]
    widths = [max([len(c)] + [len(r[i]) for r in rows]) for i, c in enumerate(cols)]
    for r in [cols] + rows:
        out.write("  ".join(v.ljust(widths[i]) for i, v in enumerate(r)).rstrip() + "\n")
    return 0


def cmd_frame(client, args, out, prog):
    accept, query = _image_query(args)
    s = _make_session(client, args)
    try:
        spp = _session_params(args, client.methods).get("spp", 1)
        prog.update("session %s: rendering %dx%d, %d spp" % (s.id, args.size[0], args.size[1], spp))
        data = client.frame(s, accept=accept, **query)
        hdr = client.last_response.headers
        _write(args.output, data)
        ms = hdr.get("X-Render-Ms")
        prog.line("frame %s: %s ms, %d bytes -> %s (served by %s)" % (
            hdr.get("X-Frame", "?"), ms or "?", len(data), args.output,
            hdr.get("X-Served-By", "?")))
        if args.json:
            n = hdr.get("X-Frame", "latest")
            out.write(json.dumps(client.get_frame(s, n, accept="json"), indent=2) + "\n")
    finally:
        client.delete_session(s, missing_ok=True)
    return 0


def _events_thread(client, session, q, stop):
    """Feeds the session's events into q until stop is set or the stream ends."""
    def run():
        try:
            stream = client.open_events(session, timeout=30.0)
            q.put(("_connected", None))
            with stream:
                for ev in parse_sse(stream):
                    if stop.is_set():
                        return
                    q.put(ev)
        except Exception as e:  # noqa: BLE001 - the poller carries on without events
            q.put(("_failed", str(e)))
    t = threading.Thread(target=run, name="restir-events", daemon=True)
    t.start()
    return t


def cmd_orbit(client, args, out, prog):
    accept, query = _image_query(args)
    ext = "png" if accept == "png" else "exr"
    os.makedirs(args.output, exist_ok=True)
    s = _make_session(client, args)
    try:
        lim = {}
        try:
            lim = client.limits()
        except RestirError:
            pass
        keys, interp = orbit_keys(s.camera, args.frames, args.fps, radius=args.radius,
                                  center=args.center, turns=args.turns,
                                  max_keys=int(lim.get("max_keys", 4096)))
        anim = {"fps": args.fps, "frames": args.frames, "interpolation": interp, "camera_keys": keys}
        q, stop = queue.Queue(), threading.Event()
        _events_thread(client, s, q, stop)
        try:
            q.get(timeout=2.0)
        except queue.Empty:
            pass
        job = client.render(s, anim)
        rid = job["id"]
        prog.update("job %s: %d frames queued (session %s)" % (rid, args.frames, s.id))
        saved = {}

        def evicted(index, detail):
            return (detail or "") + (
                " (frame %d was evicted before it was downloaded: the daemon keeps the "
                "last %s frames of a session; render fewer frames per job or raise "
                "restird --frames-kept)" % (index, s.info.get("frames_kept", "?")))

        def fetch(index, href):
            if index in saved:
                return
            try:
                data = client.frame_by_href(href, accept=accept, **query)
            except RestirError as e:
                if e.slug == "frame-evicted":
                    e.detail = evicted(index, e.detail)
                raise
            path = os.path.join(args.output, "frame_%04d.%s" % (index, ext))
            _write(path, data)
            saved[index] = path

        # Events and the job name session frame numbers; files are named by the job's frame
        # index. The job's frames are consecutive, from session frame `base`, which a poll
        # tells once a frame of the job is kept (frames_kept[0] less frames_evicted).
        state, last_poll, base = job, 0.0, None
        while True:
            try:
                name, data = q.get(timeout=0.5)
            except queue.Empty:
                name, data = None, None
            if name == "frame" and isinstance(data, dict) and data.get("job") == rid and data.get("href"):
                if base is None:
                    last_poll = 0.0     # poll now: it tells base, and offers the frame too
                else:
                    fetch(int(data["frame"]) - base, data["href"])
                ms = data.get("render_ms")
                prog.update("job %s: frame %d/%d (%s ms)" % (
                    rid, len(saved), args.frames, "%.1f" % ms if isinstance(ms, (int, float)) else "?"))
            if name in ("done", "error") or time.monotonic() - last_poll > 1.0 or name is None:
                state = client.job(s, rid)
                last_poll = time.monotonic()
                # A job offers only the frames still kept, its last ones: the first
                # frames_evicted of them are gone. (A daemon without it offers every frame.)
                first = int(state.get("frames_evicted") or 0)
                kept = state.get("frames_kept")
                if kept:
                    base = kept[0] - first
                lost = [i for i in range(first) if i not in saved]
                if lost:
                    raise RestirError(410, type=PROBLEM_PREFIX + "frame-evicted", detail=evicted(lost[0], None).strip())
                for i, href in enumerate(state.get("frames") or []):
                    fetch(first + i, href)
                pr = state.get("progress") or {}
                prog.update("job %s: %s, %s/%s frames rendered, %d saved" % (
                    rid, state.get("status"), pr.get("frames_done", "?"), pr.get("frames_total", "?"),
                    len(saved)))
                if state.get("status") in ("done", "cancelled", "failed"):
                    break
        stop.set()
        if state.get("status") == "failed":
            raise RestirError.from_problem(state.get("error") or {"detail": "job failed"}, 500)
        prog.line("orbit: %d frames -> %s (job %s %s)" % (len(saved), args.output, rid, state.get("status")))
        return 0 if state.get("status") == "done" else 1
    finally:
        client.delete_session(s, missing_ok=True)


def cmd_metrics(client, args, out, prog):
    s = _make_session(client, args)
    # A reference named for this run's session is this run's alone: it goes when the run ends,
    # however it ends. One named with --reference is the caller's and stays.
    name = args.reference or ("ref-%s" % s.id)[:64]
    finished = False
    try:
        prog.update("session %s: rendering reference %s at %d spp (%s)" % (s.id, name, args.reference_spp,
                                                                          args.reference_method))
        ref_job = client.create_reference(s, name, spp=args.reference_spp, method=args.reference_method)

        def show(stage):
            def cb(state):
                pr = state.get("progress") or {}
                prog.update("%s: %s %s/%s" % (stage, state.get("status"), pr.get("frames_done", "?"),
                                              pr.get("frames_total", "?")))
            return cb

        client.wait_job(s, ref_job, timeout=args.wait, progress=show("reference " + name))
        prog.line("reference %s done" % name)
        job = client.render(s, {"fps": args.fps, "frames": args.frames}, reference=name)
        client.wait_job(s, job, timeout=args.wait, progress=show("job %s" % job["id"]))
        text = client.job_metrics(s, job, fmt="csv")
        if text and not text.endswith("\n"):
            text += "\n"
        if args.output == "-":
            out.write(text)
        else:
            _write(args.output, text.encode("utf-8"))
        rows = list(csv.DictReader(io.StringIO(text)))
        if rows:
            last = rows[-1]
            prog.line("%d frames; last frame: mape %s rmse %s relmse %s -> %s" % (
                len(rows), last.get("mape"), last.get("rmse"), last.get("relmse"), args.output))
        finished = True
        return 0
    finally:
        # The session first: deleting it cancels a reference job still running, which could
        # otherwise store the reference after it was deleted. The reference is deleted even
        # when deleting the session fails; a failed deletion is the run's error only when the
        # run itself succeeded (otherwise the error it ended with is the one to report).
        try:
            try:
                client.delete_session(s, missing_ok=True)
            finally:
                if not args.reference:
                    client.delete_reference(s.scene, name, missing_ok=True)
        except RestirError as e:
            if finished:
                raise
            prog.line("metrics: cleaning up failed too: %s" % e)


def _scene_meshes(doc):
    shapes = doc.get("shapes") if isinstance(doc, dict) else None
    return [sh for sh in (shapes or []) if isinstance(sh, dict) and sh.get("type") == "mesh"
            and isinstance(sh.get("file"), str)]


def cmd_upload(client, args, out, prog):
    with open(args.scene_json, "rb") as f:
        raw = f.read()
    try:
        doc = json.loads(raw.decode("utf-8"))
    except (ValueError, UnicodeDecodeError) as e:
        raise UsageError("%s is not JSON: %s" % (args.scene_json, e)) from None
    assets = {}
    for path in args.assets:
        name = os.path.basename(path)
        if name in assets:
            raise UsageError("two assets named %s" % name)
        assets[name] = path
    # Mesh paths in a library scene are relative to its folder; uploaded scenes name assets by
    # their bare name. Upload the files the scene names and rewrite the paths to bare names.
    base = os.path.dirname(os.path.abspath(args.scene_json))
    rewritten = False
    for sh in _scene_meshes(doc):
        name = os.path.basename(sh["file"])
        if name not in assets:
            cand = os.path.join(base, sh["file"])
            if os.path.isfile(cand):
                assets[name] = cand
        if sh["file"] != name:
            sh["file"] = name
            rewritten = True
    if rewritten:
        prog.line("mesh paths rewritten to bare asset names")
        raw = json.dumps(doc).encode("utf-8")
    for name, path in assets.items():
        with open(path, "rb") as f:
            data = f.read()
        created = client.put_asset(args.scene_id, name, data)
        prog.line("asset %s: %s (%d bytes)" % (name, "created" if created else "stored over an existing one",
                                               len(data)))
    info = client.put_scene(args.scene_id, raw)
    what = "created" if info.get("created") else ("replaced" if info.get("replaced") else "unchanged")
    prog.line("scene %s: %s" % (args.scene_id, what))
    out.write(json.dumps(info, indent=2) + "\n")
    return 0


COMMANDS = {"health": cmd_health, "scenes": cmd_scenes, "frame": cmd_frame, "orbit": cmd_orbit,
            "metrics": cmd_metrics, "upload": cmd_upload}


def prog_name():
    """The command's name in usage and messages: restir-client when installed (pyproject.toml),
    else restir.py."""
    return "restir-client" if os.path.basename(sys.argv[0] if sys.argv else "") == "restir-client" else "restir.py"


def main(argv=None, out=None, err=None):
    out = out or sys.stdout
    err = err or sys.stderr
    parser = build_parser()
    args = parser.parse_args(argv)   # exits 2 on a usage error
    prog = Progress(args.quiet, err)
    token = None
    if args.token_file:
        try:
            with open(args.token_file, encoding="utf-8") as f:
                token = f.read().strip()
        except OSError as e:
            print("%s: --token-file: %s" % (prog_name(), e), file=err)
            return 2
    client = Client(args.server, timeout=args.timeout, log=lambda t: prog.line("note: " + t), token=token)
    try:
        return COMMANDS[args.command](client, args, out, prog)
    except UsageError as e:
        err.write("%s: %s\n" % (prog_name(), e))
        return 2
    except RestirError as e:
        prog.line("")
        err.write("%s: %s\n" % (prog_name(), e))
        if e.field is not None:
            err.write("  field: %s\n" % (json.dumps(e.field) if e.field == "" else e.field))
        if e.request_id:
            err.write("  request id: %s (served by %s)\n" % (e.request_id, e.served_by or "?"))
        return 1
    except (TimeoutError, ValueError, OSError) as e:
        err.write("%s: %s\n" % (prog_name(), e))
        return 1
    except KeyboardInterrupt:
        err.write("%s: interrupted\n" % prog_name())
        return 130


if __name__ == "__main__":
    sys.exit(main())
