"""bench/daemon.py — a build/restird for a benchmark: tests/daemon.py's daemon (an ephemeral
loopback port, a scratch data folder, logs beside it), plus one keep-alive connection over which
sessions are created and frames rendered, each frame's time as the daemon measured it (no HTTP
in it): its CPU time over its threads (cputime.frame_time_ms). Stdlib only."""
import http.client
import importlib.util
import json
import tempfile
from pathlib import Path

from cputime import frame_time_ms

# tests/daemon.py under another name: this module is `daemon` too.
_spec = importlib.util.spec_from_file_location("restird_test_daemon",
                                               Path(__file__).resolve().parent.parent / "tests" / "daemon.py")
test_daemon = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(test_daemon)


class Daemon:
    def __init__(self, binary, threads="0", *extra):
        self.data = tempfile.TemporaryDirectory(prefix="restird-bench-")
        args = (["--threads", threads] if threads != "0" else []) + list(extra)
        self.d = test_daemon.Daemon(Path(self.data.name) / "data", *args, binary=binary)
        self.port, self.pid = self.d.port, self.d.proc.pid
        self.conn = http.client.HTTPConnection("127.0.0.1", self.port, timeout=600)

    def _call(self, method, path, body=None, ok=(200,), content_type="application/json"):
        headers = {"Accept": "application/json"}
        data = None
        if body is not None:
            data = body if isinstance(body, bytes) else json.dumps(body).encode()
        if body is not None or method in ("POST", "PUT"):
            headers["Content-Type"] = content_type
        self.conn.request(method, path, body=data, headers=headers)
        r = self.conn.getresponse()
        payload = r.read()
        if r.status not in ok:
            raise SystemExit(f"bench: {method} {path}: {r.status} {payload[:300]!r}")
        return r, payload

    def put_scene(self, name, scene_json):
        """Uploads a scene (its JSON text) under `name`; it must name no mesh files."""
        self._call("PUT", f"/v1/scenes/{name}", scene_json.encode(), ok=(200, 201))

    def session(self, scene, method, width, height, params, seed=0):
        """Creates a session; returns its path."""
        r, _ = self._call("POST", f"/v1/scenes/{scene}/sessions",
                          {"method": method, "width": width, "height": height, "params": params, "seed": seed},
                          ok=(201,))
        return r.headers["Location"]

    def frame(self, session):
        """Renders the session's next frame; returns the frame's JSON (render_ms, passes, ...)."""
        return json.loads(self._call("POST", session + "/frames")[1])

    def frame_ms(self, session):
        """Renders the session's next frame; returns its time (frame_time_ms)."""
        return frame_time_ms(self.frame(session))

    def delete(self, session):
        self._call("DELETE", session, ok=(204,))

    def close(self):
        """Stops the daemon (SIGTERM) and removes its folder; returns its exit code (None: killed)."""
        self.conn.close()
        rc, _ = self.d.stop(timeout=60)
        self.data.cleanup()
        return rc
