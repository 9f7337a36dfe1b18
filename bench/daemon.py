"""bench/daemon.py — a build/restird for a benchmark: started on a free loopback port with a
scratch data folder, sessions created and frames rendered over one keep-alive connection, each
frame's time as the daemon measured it (render_ms: no HTTP in it). Stdlib only."""
import http.client
import json
import re
import subprocess
import tempfile


class Daemon:
    def __init__(self, binary, threads="0"):
        self.data = tempfile.TemporaryDirectory()
        args = [binary, "--listen", "127.0.0.1:0", "--data-dir", self.data.name]
        if threads != "0":
            args += ["--threads", threads]
        self.proc = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
        line = self.proc.stdout.readline()
        m = re.search(r":(\d+) ", line)
        if not m:
            self.close()
            raise SystemExit(f"bench: {binary} did not start: {line.strip()!r}")
        self.conn = http.client.HTTPConnection("127.0.0.1", int(m.group(1)), timeout=600)

    def _call(self, method, path, body=None, ok=(200,)):
        headers = {"Accept": "application/json"}
        data = None
        if body is not None:
            data = json.dumps(body).encode()
            headers["Content-Type"] = "application/json"
        self.conn.request(method, path, body=data, headers=headers)
        r = self.conn.getresponse()
        payload = r.read()
        if r.status not in ok:
            raise SystemExit(f"bench: {method} {path}: {r.status} {payload[:300]!r}")
        return r, payload

    def put_scene(self, name, scene_json):
        """Uploads a scene (its JSON text) under `name`; it must name no mesh files."""
        self.conn.request("PUT", f"/v1/scenes/{name}", body=scene_json.encode(),
                          headers={"Content-Type": "application/json", "Accept": "application/json"})
        r = self.conn.getresponse()
        payload = r.read()
        if r.status not in (200, 201):
            raise SystemExit(f"bench: PUT /v1/scenes/{name}: {r.status} {payload[:300]!r}")

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
        return self.frame(session)["render_ms"]

    def delete(self, session):
        self._call("DELETE", session, ok=(204,))

    def close(self):
        self.proc.terminate()
        self.proc.wait()
        self.data.cleanup()
