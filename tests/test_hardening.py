"""The daemon against whoever can reach its port: request framing (a body framed one way only),
HEAD, Host and Origin checks, the bearer token, log lines a request cannot forge, and paths in
the data directory that are not followed through symlinks.

Every request goes to 127.0.0.1; every test bounds its own time (socket timeouts)."""
import http.client
import os
import socket
import time

import pytest

from daemon import Daemon
from test_daemon import CORNELL, J, P, TETRA_PLY, assert_problem

SPHERE = {"camera": {"position": [0, 0, 5], "look_at": [0, 0, 0], "up": [0, 1, 0], "fov_deg": 30},
          "materials": {"w": {"type": "diffuse", "albedo": [0.5, 0.5, 0.5]}},
          "shapes": [{"type": "sphere", "material": "w", "center": [0, 0, 0], "radius": 1}],
          "environment": {"radiance": [1, 1, 1]}}


@pytest.fixture(scope="module")
def daemon(tmp_path_factory):
    d = Daemon(tmp_path_factory.mktemp("hardening") / "data", "--threads", "1")
    yield d
    rc, _ = d.stop()
    assert rc == 0, d.stderr()[-3000:]


class Raw:
    """The answer to bytes sent as they are: status, headers, body, and whether the daemon closed
    the connection after it."""

    def __init__(self, status, headers, body, closed):
        self.status, self.headers, self.body, self.closed = status, headers, body, closed

    def header(self, name, default=None):
        return self.headers.get(name, default)

    def json(self):
        import json
        return json.loads(self.body)

    def __repr__(self):
        return f"HTTP {self.status} {dict(self.headers)} {self.body[:400]!r} closed={self.closed}"


def send_raw(d, data, method="GET", timeout=10):
    """Sends `data` exactly and reads one answer (None when the daemon closed without one)."""
    sock = socket.create_connection(("127.0.0.1", d.port), timeout=timeout)
    try:
        sock.sendall(data)
        r = http.client.HTTPResponse(sock, method=method)
        try:
            r.begin()
        except http.client.RemoteDisconnected:
            return None
        body = r.read()
        try:
            closed = sock.recv(1) == b""
        except socket.timeout:
            closed = False
        return Raw(r.status, r.headers, body, closed)
    finally:
        sock.close()


def log_lines(d):
    return d.stderr().splitlines()


# ---- framing ----

def test_two_content_lengths_refused_and_nothing_smuggled(daemon):
    smuggled = b"GET /v1/smuggled-path HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n"
    for lengths in ((2, 2 + len(smuggled)), (2 + len(smuggled), 2), (2, 2)):
        head = (f"POST {CORNELL}/sessions HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\n"
                f"Content-Length: {lengths[0]}\r\nContent-Length: {lengths[1]}\r\n\r\n").encode()
        r = send_raw(daemon, head + b"{}" + smuggled, "POST")
        assert r is not None, lengths
        body = assert_problem(r, 400, "bad-header", "Content-Length", str(lengths))
        assert body["detail"] == "the request has more than one Content-Length header"
        assert r.header("Connection") == "close" and r.closed, repr(r)
    time.sleep(0.2)
    assert "/v1/smuggled-path" not in daemon.stderr()
    assert daemon.req("GET", f"{CORNELL}/sessions").json()["sessions"] == []


@pytest.mark.parametrize("te, extra, why", [
    (["identity", "chunked"], [], "the request has more than one Transfer-Encoding header"),
    (["chunked", "chunked"], [], "the request has more than one Transfer-Encoding header"),
    (["identity"], ["Content-Length: 2"], "the request has both Transfer-Encoding and Content-Length"),
    (["chunked"], ["Content-Length: 2"], "the request has both Transfer-Encoding and Content-Length"),
    (["identity"], [], "the only Transfer-Encoding accepted is chunked"),
    (["gzip, chunked"], [], "the only Transfer-Encoding accepted is chunked"),
])
def test_conflicting_transfer_encoding_refused(daemon, te, extra, why):
    lines = [f"POST {CORNELL}/sessions HTTP/1.1", "Host: 127.0.0.1", "Content-Type: application/json"]
    lines += [f"Transfer-Encoding: {v}" for v in te] + extra
    t0 = time.monotonic()
    r = send_raw(daemon, ("\r\n".join(lines) + "\r\n\r\n").encode() + b"2\r\n{}\r\n0\r\n\r\n", "POST")
    assert r is not None and time.monotonic() - t0 < 5, (te, extra)
    body = assert_problem(r, 400, "bad-header", "Transfer-Encoding", repr(te))
    assert body["detail"] == why
    assert r.closed, repr(r)
    assert daemon.alive()
    assert daemon.req("GET", "/healthz").status == 200


def test_http11_without_host_refused_and_http10_without_host_served(daemon):
    r = send_raw(daemon, b"GET /v1/limits HTTP/1.1\r\n\r\n")
    body = assert_problem(r, 400, "bad-header", "Host")
    assert body["detail"] == "an HTTP/1.1 request needs a Host header"
    r = send_raw(daemon, b"GET /v1/limits HTTP/1.1\r\nHost: 127.0.0.1\r\nHost: 127.0.0.1\r\n\r\n")
    assert_problem(r, 400, "bad-header", "Host")
    r = send_raw(daemon, b"GET /healthz HTTP/1.0\r\n\r\n")
    assert r.status == 200 and r.json() == {"status": "ok"}, repr(r)


def test_head_answers_like_get_without_a_body(daemon):
    for path in ("/healthz", "/v1/limits", f"{CORNELL}", "/"):
        get = daemon.req("GET", path)
        head = daemon.req("HEAD", path)
        assert head.status == 200 == get.status, (path, head)
        assert head.body == b"", path
        assert head.header("Content-Type") == get.header("Content-Type"), path
        assert head.header("Content-Length") == str(len(get.body)), path
    r = daemon.req("HEAD", "/v1/nowhere")
    assert r.status == 404 and r.body == b"", repr(r)
    r = daemon.req("DELETE", "/v1/limits")
    assert_problem(r, 405, "method-not-allowed")
    assert r.header("Allow") == "GET, HEAD", repr(r)


def test_control_characters_cannot_forge_a_log_line(daemon):
    forged = "2026-01-01T00:00:00Z GET /v1/forged 200 0 0.1 x"
    path = "/v1/x%0a" + forged.replace(" ", "%20") + "%0d%1b[31m"
    r = daemon.req("GET", path)
    assert_problem(r, 404, "not-found")
    time.sleep(0.2)
    lines = log_lines(daemon)
    assert not any(line.startswith("2026-01-01T00:00:00Z") for line in lines)
    rid = r.header("X-Request-Id")
    mine = [line for line in lines if line.endswith(" " + rid)]
    assert len(mine) == 1, lines[-5:]
    assert " /v1/x%0A2026-01-01T00:00:00Z%20GET%20/v1/forged%20200%200%200.1%20x%0D%1B[31m 404 " in mine[0], mine


def test_sphere_radius_out_of_float_range_names_its_field(daemon):
    scene = dict(SPHERE, shapes=[dict(SPHERE["shapes"][0], radius=3e38)])
    r = daemon.req("PUT", "/v1/scenes/huge-sphere", json_body=scene)
    body = assert_problem(r, 422, "invalid-scene", "/shapes/0/radius")
    assert "32-bit float range" in body["detail"], body


def test_symlinked_folders_in_the_data_directory_are_not_followed(tmp_path):
    d = Daemon(tmp_path / "data", "--threads", "1")
    try:
        outside = tmp_path / "outside"
        outside.mkdir()
        scenes = tmp_path / "data" / "scenes"
        # A link planted where a new scene's folder would go: nothing is written through it.
        (scenes / "planted").symlink_to(outside, target_is_directory=True)
        r = d.req("PUT", "/v1/scenes/planted", json_body=SPHERE)
        body = assert_problem(r, 500, "internal")
        assert "is a symbolic link" in body["detail"], body
        r = d.req("PUT", "/v1/scenes/planted/assets/m.ply", body=TETRA_PLY, headers={"Content-Type": "model/ply"})
        assert_problem(r, 500, "internal")
        assert list(outside.iterdir()) == []
        # A scene's folder swapped for a link while the daemon runs: nothing is deleted through it.
        assert d.req("PUT", "/v1/scenes/victim", json_body=SPHERE).status == 201
        (outside / "scene.json").write_text("{}")
        victim = scenes / "victim"
        (victim / "scene.json").unlink()
        victim.rmdir()
        victim.symlink_to(outside, target_is_directory=True)
        r = d.req("DELETE", "/v1/scenes/victim")
        assert_problem(r, 500, "internal")
        assert (outside / "scene.json").read_text() == "{}"
        r = d.req("PUT", "/v1/scenes/victim", json_body=dict(SPHERE, environment={"radiance": [2, 2, 2]}))
        assert_problem(r, 500, "internal")
        assert sorted(p.name for p in outside.iterdir()) == ["scene.json"]
    finally:
        rc, _ = d.stop()
        assert rc == 0, d.stderr()[-3000:]
