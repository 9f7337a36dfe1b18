"""Three daemons behind HAProxy on loopback ports, routed by docker/haproxy.cfg as compose uses
it (make test-cluster; no Docker engine needed).

- Every request of a scene reaches one daemon (X-Served-By), the only one that holds the scene;
  the others answer 404 scene-not-loaded.
- When a daemon dies (SIGKILL), only its scenes move, each to one survivor; the Python client
  uploads them again and re-creates their sessions, and no call the user makes fails.
- When the daemon is back on its address, its scenes return to it (the hash ring is the same),
  it has them from its data directory, and the client re-creates their sessions there.

Ports are chosen by the OS, never fixed. Every process started here is stopped by the
fixture, also when a test fails."""
import shutil
import signal
import socket
import subprocess
import sys
import time
import urllib.parse
from collections import Counter
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent.parent
sys.path.insert(0, str(ROOT / "tests"))
sys.path.insert(0, str(ROOT / "clients" / "python"))
import restir  # noqa: E402
from daemon import Daemon  # noqa: E402

HAPROXY = shutil.which("haproxy") or "/usr/sbin/haproxy"   # /usr/sbin is not on every PATH
P = "urn:restird:problem:"
TETRA_PLY = (ROOT / "tests" / "meshes" / "tetra.ply").read_bytes()
SESSION = {"width": 16, "height": 16, "params": {"spp": 1}}
BUILTIN = ["cornell-box", "furnace"]


def sphere_scene(radiance):
    return {"camera": {"position": [0, 0, 5], "look_at": [0, 0, 0], "up": [0, 1, 0], "fov_deg": 30},
            "materials": {"w": {"type": "diffuse", "albedo": [0.5, 0.5, 0.5]}},
            "shapes": [{"type": "sphere", "material": "w", "center": [0, 0, 0], "radius": 1}],
            "environment": {"radiance": [radiance] * 3}}


def mesh_scene():
    return {"camera": {"position": [0, 0, -6], "look_at": [0, 0, 0], "up": [0, 1, 0], "fov_deg": 40},
            "materials": {"w": {"type": "diffuse", "albedo": [0.5, 0.5, 0.5]}},
            "shapes": [{"type": "mesh", "material": "w", "file": "tetra.ply"}],
            "environment": {"radiance": [1, 1, 1]}}


class RecordingClient(restir.Client):
    """The Python client, recording who served every answer it got: (method, path, status, daemon)."""

    def __init__(self, server):
        self.notes = []
        super().__init__(server, timeout=60, log=self.notes.append)
        self.answers = []

    def _send_once(self, method, url, body, headers, timeout):
        resp = super()._send_once(method, url, body, headers, timeout)
        self.answers.append((method, urllib.parse.urlsplit(url).path, resp.status, resp.headers.get("X-Served-By")))
        return resp

    def served_by(self):
        return self.answers[-1][3]


def scene_of(path):
    parts = path.split("/")
    return parts[3] if len(parts) > 3 and parts[1:3] == ["v1", "scenes"] else None


class Cluster:
    def __init__(self, tmp):
        self.tmp = tmp
        self.daemons = {}        # id -> Daemon
        self.proxy = None
        self.sock = tmp / "haproxy.sock"

    def start_daemon(self, name, port=0):
        self.daemons[name] = Daemon(self.tmp / name, "--id", name, "--threads", "1", "--listen", f"127.0.0.1:{port}")
        return self.daemons[name]

    def start(self):
        for i in range(3):
            self.start_daemon(f"restird-{i}")
        for _ in range(3):   # the proxy's port is free when chosen; another process may take it first
            with socket.socket() as s:
                s.bind(("127.0.0.1", 0))
                self.port = s.getsockname()[1]
            env = {"RESTIRD_PROXY_BIND": f"127.0.0.1:{self.port}", "RESTIRD_HAPROXY_SOCKET": str(self.sock),
                   **{f"RESTIRD_{i}": f"127.0.0.1:{self.daemons[f'restird-{i}'].port}" for i in range(3)},
                   "PATH": "/usr/sbin:/usr/bin:/bin"}
            log = open(self.tmp / "haproxy.log", "ab")
            self.proxy = subprocess.Popen([HAPROXY, "-db", "-f", str(ROOT / "docker" / "haproxy.cfg")], env=env,
                                          stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL)
            log.close()
            self.wait(lambda: self.proxy.poll() is not None or self.sock.exists() and self.accepts(), 10)
            if self.proxy.poll() is None:
                break
        assert self.proxy.poll() is None and self.accepts(), self.log()
        self.wait_states({name: "UP" for name in self.daemons})

    def accepts(self):
        try:
            socket.create_connection(("127.0.0.1", self.port), timeout=1).close()
            return True
        except OSError:
            return False

    @staticmethod
    def wait(cond, timeout):
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if cond():
                return True
            time.sleep(0.05)
        return False

    def states(self):
        """HAProxy's view of each daemon: UP, DOWN, ... (from the runtime API's `show stat`)."""
        with socket.socket(socket.AF_UNIX) as s:
            s.connect(str(self.sock))
            s.sendall(b"show stat\n")
            data = b""
            while chunk := s.recv(65536):
                data += chunk
        lines = data.decode().splitlines()
        head = lines[0].lstrip("# ").split(",")
        rows = [dict(zip(head, line.split(","))) for line in lines[1:] if line]
        return {r["svname"]: r["status"] for r in rows if r["pxname"] == "restird" and r["svname"] in self.daemons}

    def wait_states(self, want, timeout=20):
        assert self.wait(lambda: self.states() == want, timeout), (self.states(), want, self.log())

    def log(self):
        path = self.tmp / "haproxy.log"
        return path.read_text(errors="replace")[-3000:] if path.exists() else ""

    def holds(self, name, scene):
        r = self.daemons[name].req("GET", f"/v1/scenes/{scene}")
        assert r.header("X-Served-By") == name, repr(r)
        if r.status == 404:
            assert r.json()["type"] == P + "scene-not-loaded", repr(r)
            return False
        assert r.status == 200, repr(r)
        return True

    def stop(self):
        """Stops everything still running; returns the daemons' exit codes."""
        if self.proxy and self.proxy.poll() is None:
            self.proxy.send_signal(signal.SIGTERM)
            try:
                self.proxy.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.proxy.kill()
                self.proxy.wait()
        return {name: d.stop()[0] for name, d in self.daemons.items() if d.alive()}


@pytest.fixture
def cluster(tmp_path):
    c = Cluster(tmp_path)
    try:
        c.start()
        yield c
    finally:
        c.stop()


def test_daemons_started_together_give_different_session_ids(cluster):
    # After a scene moves, a client's old session id reaches another daemon: that daemon must
    # not know the id as one of its own sessions (a 404 makes the client re-create it).
    ids = [d.req("POST", "/v1/scenes/furnace/sessions", json_body=SESSION).json()["id"]
           for d in cluster.daemons.values()]
    assert len(set(ids)) == len(ids), ids


def upload_scenes(client):
    """Nine uploaded scenes (three with a mesh asset), so that each daemon gets some."""
    scenes = []
    for i in range(9):
        name = f"cluster-{i}"
        if i % 3 == 0:
            client.upload_scene(name, mesh_scene(), {"tetra.ply": TETRA_PLY})
        else:
            client.put_scene(name, sphere_scene(0.5 + 0.1 * i))
        scenes.append(name)
    return scenes


def owners_from(client, scenes):
    """The daemon that answered each scene's requests; fails when a scene reached two."""
    seen = {}
    for method, path, status, by in client.answers:
        scene = scene_of(path)
        if scene in scenes:
            seen.setdefault(scene, set()).add(by)
    for scene in scenes:
        assert len(seen.get(scene, ())) == 1, (scene, seen.get(scene), client.answers)
    return {scene: next(iter(by)) for scene, by in seen.items()}


def test_every_request_of_a_scene_reaches_one_daemon(cluster):
    c = RecordingClient(f"http://127.0.0.1:{cluster.port}")
    scenes = upload_scenes(c)
    for scene in scenes + BUILTIN:
        c.get_scene(scene)
        s = c.create_session(scene, **SESSION)
        c.list_sessions(scene)
        s.frame(accept="json")
        s.frame(camera={"fov_deg": 35})
        c.get_frame(s, "latest", accept="json")    # a 303 to /frames/1, followed
        c.accumulation(s, accept="json")
        job = c.render(s, {"fps": 10, "frames": 2})
        c.wait_job(s, job, timeout=60, poll=0.02)
        c.job_metrics(s, job)
        s.delete()
    assert all(status < 400 for _, _, status, _ in c.answers), [a for a in c.answers if a[2] >= 400]
    assert not c.notes, c.notes
    owners = owners_from(c, scenes + BUILTIN)
    uploaded = {scene: owners[scene] for scene in scenes}
    assert len(set(uploaded.values())) >= 2, uploaded
    # The owner is the only daemon holding an uploaded scene; the others say so with a problem.
    for scene, owner in uploaded.items():
        assert [name for name in cluster.daemons if cluster.holds(name, scene)] == [owner], scene
    # Built-in scenes are on every daemon: their requests still go to one.
    for scene in BUILTIN:
        assert all(cluster.holds(name, scene) for name in cluster.daemons)


def uploads(answers):
    """The scenes uploaded (PUT /v1/scenes/{scene}) in these answers."""
    return {scene_of(path) for method, path, _, _ in answers if method == "PUT" and path.count("/") == 3}


def frame_round(client, sessions, next_frame):
    """One frame of every session through the client; returns the daemon that rendered each.
    next_frame[scene] is the frame number the session must answer with (0 once re-created)."""
    served = {}
    for scene, s in sessions.items():
        stats = s.frame(accept="json")
        served[scene] = client.served_by()
        assert stats["frame"] == next_frame[scene], (scene, stats, s.id)
        next_frame[scene] += 1
    return served


def test_losing_a_daemon_moves_only_its_scenes_and_the_client_recovers(cluster):
    c = RecordingClient(f"http://127.0.0.1:{cluster.port}")
    scenes = upload_scenes(c)
    sessions = {scene: c.create_session(scene, **SESSION) for scene in scenes + BUILTIN}
    next_frame = dict.fromkeys(sessions, 0)
    owners = frame_round(c, sessions, next_frame)
    assert owners == owners_from(c, scenes + BUILTIN)
    victim, _ = Counter(owners[s] for s in scenes).most_common(1)[0]
    lost = {scene for scene, owner in owners.items() if owner == victim}
    kept = set(owners) - lost
    assert lost and kept, owners

    # SIGKILL: the daemon's sessions die with it, and HAProxy may not have noticed yet.
    d = cluster.daemons[victim]
    victim_port = d.port
    d.proc.kill()
    d.proc.wait()
    mark = len(c.answers)
    next_frame.update(dict.fromkeys(lost, 0))     # a re-created session starts at frame 0
    after = frame_round(c, sessions, next_frame)     # raises if any call fails
    for scene in kept:
        assert after[scene] == owners[scene] and sessions[scene].recreated == 0, scene
    for scene in lost:
        assert after[scene] in cluster.daemons and after[scene] != victim, (scene, after[scene])
        assert sessions[scene].recreated == 1, scene
    assert uploads(c.answers[mark:]) == lost & set(scenes), c.answers[mark:]
    # The proxy itself never failed a request: the only errors were the daemons' 404s that the
    # client recovers from.
    assert {a[2] for a in c.answers[mark:] if a[2] >= 400} == {404}, c.answers[mark:]
    for scene in lost & set(scenes):
        assert cluster.holds(after[scene], scene)

    # Once HAProxy marks the daemon down the ring agrees: nothing moves again.
    cluster.wait_states({name: "DOWN" if name == victim else "UP" for name in cluster.daemons})
    assert frame_round(c, sessions, next_frame) == after
    assert all(sessions[scene].recreated == (1 if scene in lost else 0) for scene in sessions)

    # Back on its address with its data directory: its scenes return, already loaded there.
    cluster.start_daemon(victim, victim_port)
    cluster.wait_states({name: "UP" for name in cluster.daemons})
    mark = len(c.answers)
    next_frame.update(dict.fromkeys(lost, 0))
    assert frame_round(c, sessions, next_frame) == owners
    assert all(sessions[scene].recreated == (2 if scene in lost else 0) for scene in sessions)
    assert not uploads(c.answers[mark:]), c.answers[mark:]

    # No daemon crashed along the way (under SAN=1: no sanitizer report either).
    codes = cluster.stop()
    assert codes == {name: 0 for name in cluster.daemons}, (codes, {n: d.stderr()[-2000:] for n, d in
                                                                      cluster.daemons.items()})
