"""Faults the daemon must survive without losing a scene it accepted: a client that goes away
in the middle of an upload or of a response, a full disk under the data directory, SIGTERM
during a job, and a corrupted file in the data directory at restart.

The full disk is a file-size limit (RLIMIT_FSIZE, set on the daemon alone before it starts):
a write past it fails with EFBIG like a write to a full file system fails with ENOSPC, needs
no privilege, and leaves the machine's disks alone. The daemon ignores SIGXFSZ so the limit
reaches it as an error."""
import json
import resource
import socket
import struct
import time

import pytest

from test_daemon import CORNELL, TETRA_PLY, Daemon, assert_problem, cornell_scene, new_session, put_mesh_scene

FSIZE_LIMIT = 256 << 10   # bytes any one file of the daemon may reach


def limit_file_size():
    resource.setrlimit(resource.RLIMIT_FSIZE, (FSIZE_LIMIT, FSIZE_LIMIT))


def padded_scene(size, **light):
    """The Cornell box as JSON text of about `size` bytes (trailing spaces are still JSON)."""
    text = json.dumps(cornell_scene(**light))
    return (text + " " * max(0, size - len(text))).encode()


def leftovers(data):
    return sorted(str(p) for p in data.rglob(".tmp-*"))


def stop_ok(d):
    rc, took = d.stop()
    assert rc == 0 and took < 30, d.stderr()[-3000:]


def abort_connection(sock):
    """Closes with a reset (SO_LINGER 0): the daemon sees the peer vanish, not a clean close."""
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
    sock.close()


def test_full_disk_refused_with_507_and_accepted_scenes_kept(tmp_path):
    data = tmp_path / "data"
    d = Daemon(data, "--threads", "1", preexec_fn=limit_file_size)
    try:
        r = d.req("PUT", "/v1/scenes/small", body=padded_scene(0), headers={"Content-Type": "application/json"})
        assert r.status == 201, repr(r)
        kept_hash = r.json()["hash"]
        # A new scene, a replacement and an asset that do not fit are each refused with a clear
        # error; nothing half-written stays behind and the accepted scene is untouched.
        big = padded_scene(FSIZE_LIMIT + 1000, emission=[3, 3, 3])
        for path in ("/v1/scenes/too-big", "/v1/scenes/small"):
            r = d.req("PUT", path, body=big, headers={"Content-Type": "application/json"})
            body = assert_problem(r, 507, "insufficient-storage", where=path)
            assert "File too large" in body["detail"], body
        big_ply = TETRA_PLY.replace(b"end_header\n", b"comment " + b"x" * FSIZE_LIMIT + b"\nend_header\n")
        r = d.req("PUT", "/v1/scenes/small/assets/big.ply", body=big_ply, headers={"Content-Type": "model/ply"})
        assert_problem(r, 507, "insufficient-storage")
        assert_problem(d.req("GET", "/v1/scenes/too-big"), 404, "scene-not-loaded")
        assert d.req("GET", "/v1/scenes/small").json()["hash"] == kept_hash
        assert leftovers(data) == []
        assert d.req("GET", "/v1/limits").json()["memory_used"]["scenes"] == \
            d.req("GET", "/v1/scenes/small").json()["scene_bytes"]  # refused uploads hold nothing
        s = new_session(d, "small", width=8, height=8)
        assert d.req("POST", s["href"] + "/frames").status == 200
    finally:
        stop_ok(d)
    d = Daemon(data, "--threads", "1")  # the disk has room again: everything accepted is back
    try:
        assert d.req("GET", "/v1/scenes/small").json()["hash"] == kept_hash
        assert_problem(d.req("GET", "/v1/scenes/too-big"), 404, "scene-not-loaded")
        assert "skipping" not in d.stderr(), d.stderr()[-2000:]
    finally:
        stop_ok(d)


@pytest.mark.concurrency
def test_client_gone_mid_upload(tmp_path):
    d = Daemon(tmp_path / "data", "--threads", "1")
    try:
        cases = [("PUT", "/v1/scenes/half", "application/json", padded_scene(20000)),
                 ("PUT", "/v1/scenes/half-mesh/assets/tetra.ply", "model/ply", TETRA_PLY * 40),
                 ("PUT", f"{CORNELL}/references/half", "image/x-exr", b"\x76\x2f\x31\x01" + b"\0" * 20000)]
        for method, path, ctype, body in cases:
            for cut, reset in ((len(body) // 2, False), (len(body) // 3, True), (0, True)):
                sock = socket.create_connection(("127.0.0.1", d.port), timeout=10)
                sock.sendall(f"{method} {path} HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: {ctype}\r\n"
                             f"Content-Length: {len(body)}\r\n\r\n".encode() + body[:cut])
                if reset:
                    abort_connection(sock)
                else:
                    sock.close()
        time.sleep(0.3)
        assert d.alive(), d.stderr()[-3000:]
        assert_problem(d.req("GET", "/v1/scenes/half"), 404, "scene-not-loaded")
        assert d.req("GET", "/v1/limits").json()["memory_used"]["references"] == 0  # no half reference
        assert leftovers(tmp_path / "data") == []
        # The same uploads, whole, go through afterwards.
        assert d.req("PUT", "/v1/scenes/half", body=padded_scene(20000),
                     headers={"Content-Type": "application/json"}).status == 201
        assert d.req("PUT", "/v1/scenes/half-mesh/assets/tetra.ply", body=TETRA_PLY,
                     headers={"Content-Type": "model/ply"}).status == 201
        assert d.req("GET", "/healthz").status == 200
    finally:
        stop_ok(d)


@pytest.mark.concurrency
def test_client_gone_mid_response(tmp_path):
    d = Daemon(tmp_path / "data", "--threads", "1")
    try:
        s = new_session(d, width=512, height=512)  # a float EXR of about 3 MiB per frame
        for i in range(4):
            sock = socket.create_connection(("127.0.0.1", d.port), timeout=60)
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
            sock.sendall(f"POST {s['href']}/frames HTTP/1.1\r\nHost: 127.0.0.1\r\nAccept: image/x-exr\r\n"
                         "Content-Type: application/json\r\nContent-Length: 0\r\n\r\n".encode())
            assert sock.recv(1024).startswith(b"HTTP/1.1 200"), "no answer started"
            abort_connection(sock)
        # An event stream dropped while it is open.
        sock = socket.create_connection(("127.0.0.1", d.port), timeout=10)
        sock.sendall(f"GET {s['href']}/events HTTP/1.1\r\nHost: 127.0.0.1\r\n"
                     "Accept: text/event-stream\r\n\r\n".encode())
        assert sock.recv(1024).startswith(b"HTTP/1.1 200")
        abort_connection(sock)
        time.sleep(0.3)
        assert d.alive(), d.stderr()[-3000:]
        # Each dropped answer was a frame rendered and kept; the session goes on from there.
        assert d.req("GET", s["href"]).json()["frames_rendered"] == 4
        r = d.req("POST", s["href"] + "/frames", headers={"Accept": "application/json"})
        assert r.status == 200 and r.json()["frame"] == 4, repr(r)
        assert d.req("GET", s["href"] + "/frames/3", headers={"Accept": "image/x-exr"}).status == 200
    finally:
        stop_ok(d)


@pytest.mark.concurrency
def test_sigterm_during_job_keeps_scenes(tmp_path):
    data = tmp_path / "data"
    d = Daemon(data, "--threads", "1")
    try:
        h = put_mesh_scene(d, "mesh").json()["hash"]
        s = new_session(d, "mesh", width=32, height=32)
        r = d.req("POST", s["href"] + "/renders", json_body={"animation": {"frames": 5000}})
        assert r.status == 202, repr(r)
        deadline = time.monotonic() + 30
        while d.req("GET", r.header("Location")).json()["progress"]["frames_done"] < 1:
            assert time.monotonic() < deadline
            time.sleep(0.02)
    finally:
        stop_ok(d)
    assert "stopped" in d.stderr()
    d = Daemon(data, "--threads", "1")
    try:
        assert d.req("GET", "/v1/scenes/mesh").json()["hash"] == h
        s = new_session(d, "mesh", width=8, height=8)
        assert d.req("POST", s["href"] + "/frames").status == 200
    finally:
        stop_ok(d)


@pytest.mark.parametrize("damage", ["truncated-json", "garbage-json", "truncated-asset", "empty-json"])
def test_corrupt_file_at_restart_is_named_and_others_load(tmp_path, damage):
    data = tmp_path / "data"
    d = Daemon(data, "--threads", "1")
    try:
        assert put_mesh_scene(d, "victim").status == 201
        keep = d.req("PUT", "/v1/scenes/bystander", json_body=cornell_scene(emission=[4, 4, 4])).json()["hash"]
    finally:
        stop_ok(d)
    victim = data / "scenes" / "victim"
    target = {"truncated-json": victim / "scene.json", "garbage-json": victim / "scene.json",
              "empty-json": victim / "scene.json", "truncated-asset": victim / "assets" / "tetra.ply"}[damage]
    original = target.read_bytes()
    target.write_bytes({"truncated-json": original[:len(original) // 2], "garbage-json": b"\x00\xff{{",
                        "empty-json": b"", "truncated-asset": original[:len(original) // 2]}[damage])
    d = Daemon(data, "--threads", "1")
    try:
        assert_problem(d.req("GET", "/v1/scenes/victim"), 404, "scene-not-loaded")
        assert d.req("GET", "/v1/scenes/bystander").json()["hash"] == keep
        # The log names the scene and the file it could not read; the file stays for repair.
        log = d.stderr()
        assert "skipping uploaded scene 'victim'" in log and str(victim) in log, log[-2000:]
        assert target.exists()
    finally:
        stop_ok(d)
    target.write_bytes(original)  # repaired by hand: the scene is back at the next start
    d = Daemon(data, "--threads", "1")
    try:
        assert d.req("GET", "/v1/scenes/victim").status == 200
    finally:
        stop_ok(d)
