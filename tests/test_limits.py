"""Every limit GET /v1/limits lists, crossed at its boundary on a daemon started with small
limits: the value at the limit is accepted, one past it is refused with the exact status,
problem type, `field` pointer and `limit`; budgets refuse with 503 + Retry-After and give their
bytes back when the holder goes."""
import http.client
import json
import time

import numpy as np
import pytest
import yaml

from test_daemon import (CORNELL, J, P, ROOT, TETRA_PLY, Daemon, assert_problem, cornell_scene, new_session,
                         put_mesh_scene, write_exr)

SIDE, PIXELS, SPP, FRAMES, KEYS, SESSIONS = 64, 2048, 8, 5, 3, 4
JSON_BODY, ASSET_BODY, REFERENCE_BODY, KEPT = 4096, 2048, 4096, 2
WORK = 2 * PIXELS   # samples of one frame or reference: a full-size image at 2 spp


def limits_args(**over):
    opts = {"--max-side": SIDE, "--max-pixels": PIXELS, "--max-spp": SPP, "--max-frames": FRAMES,
            "--max-keys": KEYS, "--max-sessions": SESSIONS, "--max-json-body": JSON_BODY,
            "--max-asset-body": ASSET_BODY, "--max-reference-body": REFERENCE_BODY, "--frames-kept": KEPT,
            "--max-work": WORK, "--threads": 1}
    opts.update(over)
    return [str(x) for kv in opts.items() for x in kv]


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    d = Daemon(tmp_path_factory.mktemp("limits") / "data", *limits_args())
    yield d
    rc, _ = d.stop()
    assert rc == 0, d.stderr()[-3000:]


def refused(r, status, slug, field, limit):
    body = assert_problem(r, status, slug, field)
    assert body.get("limit") == limit, repr(r)
    return body


def create(d, **body):
    return d.req("POST", f"{CORNELL}/sessions", json_body=body)


def session_events(d, session_href, act):
    """The (type, data) events of the session from before act() runs up to the `done` or
    `error` event of the job whose id act() returns."""
    conn = http.client.HTTPConnection("127.0.0.1", d.port, timeout=30)
    try:
        conn.request("GET", session_href + "/events", headers={"Accept": "text/event-stream"})
        resp = conn.getresponse()
        assert resp.status == 200, resp.status
        rid, events, fields = act(), [], {}
        while not events or events[-1][0] not in ("done", "error") or events[-1][1].get("job") != rid:
            raw = resp.readline()
            assert raw, f"the event stream ended; events so far: {events}"
            line = raw.decode().rstrip("\r\n")
            if line and not line.startswith(":"):
                k, v = line.split(":", 1)
                fields[k] = v.lstrip(" ")
            elif not line and "event" in fields:
                events.append((fields["event"], json.loads(fields.get("data", "null"))))
                fields = {}
        return events
    finally:
        conn.close()


def delete_all_sessions(d):
    for s in d.req("GET", f"{CORNELL}/sessions").json()["sessions"]:
        assert d.req("DELETE", s["href"]).status == 204


def test_limits_listed(small):
    lim = small.req("GET", "/v1/limits").json()
    assert (lim["max_side"], lim["max_pixels"], lim["max_spp"], lim["max_frames"], lim["max_keys"],
            lim["max_sessions"], lim["max_json_body"], lim["max_asset_body"], lim["max_reference_body"],
            lim["frames_kept"], lim["max_work"]) == (SIDE, PIXELS, SPP, FRAMES, KEYS, SESSIONS, JSON_BODY,
                                                     ASSET_BODY, REFERENCE_BODY, KEPT, WORK)


def test_resolution_and_spp_boundaries(small):
    try:
        for body in ({"width": SIDE, "height": 1}, {"width": 1, "height": SIDE}, {"width": SIDE, "height": PIXELS // SIDE},
                     {"width": 4, "height": 4, "params": {"spp": SPP}}):
            r = create(small, **body)
            assert r.status == 201, (body, r)
            delete_all_sessions(small)
        refused(create(small, width=SIDE + 1, height=1), 422, "limit-exceeded", "/width", SIDE)
        refused(create(small, width=1, height=SIDE + 1), 422, "limit-exceeded", "/height", SIDE)
        refused(create(small, width=SIDE, height=PIXELS // SIDE + 1), 422, "limit-exceeded", "", PIXELS)
        refused(create(small, width=4, height=4, params={"spp": SPP + 1}), 422, "limit-exceeded", "/params/spp", SPP)
    finally:
        delete_all_sessions(small)


def test_frames_keys_and_reference_spp_boundaries(small):
    s = new_session(small, width=4, height=4)
    try:
        keys = [{"t": i, "fov_deg": 30 + i} for i in range(KEYS + 1)]
        r = small.req("POST", s["href"] + "/renders", json_body={"animation": {"frames": FRAMES + 1}})
        refused(r, 422, "limit-exceeded", "/animation/frames", FRAMES)
        r = small.req("POST", s["href"] + "/renders",
                      json_body={"animation": {"frames": 1, "camera_keys": keys}})
        refused(r, 422, "limit-exceeded", "/animation/camera_keys", KEYS)
        r = small.req("POST", s["href"] + "/references/r1", json_body={"spp": SPP + 1})
        refused(r, 422, "limit-exceeded", "/spp", SPP)
        r = small.req("POST", s["href"] + "/renders",
                      json_body={"animation": {"frames": FRAMES, "camera_keys": keys[:KEYS]}})
        assert r.status == 202, repr(r)
    finally:
        assert small.req("DELETE", s["href"]).status == 204


def test_work_boundary(small):
    """max_work bounds the samples of one request (pixels x spp): a frame of a session, a
    reference. At the limit it is accepted; past it 422 names the value and the limit."""
    try:
        s = new_session(small, width=SIDE, height=PIXELS // SIDE, params={"spp": 2})   # exactly WORK
        r = small.req("POST", s["href"] + "/frames", headers={"Accept": "application/json"})
        assert r.status == 200, repr(r)
        body = refused(create(small, width=SIDE, height=PIXELS // SIDE, params={"spp": 3}), 422, "limit-exceeded",
                       "/params/spp", WORK)
        assert body["detail"] == (f"a frame of this session takes {3 * PIXELS} samples (pixels x spp), over max_work "
                                  f"({WORK}): fewer pixels or samples, or more frames of fewer samples")
        # restir_pt renders one sample per pixel per frame.
        assert create(small, method="restir_pt", width=SIDE, height=PIXELS // SIDE).status == 201
        r = small.req("POST", s["href"] + "/references/at-limit", json_body={"spp": 2})
        assert r.status == 202, repr(r)
        body = refused(small.req("POST", s["href"] + "/references/over", json_body={"spp": 3}), 422,
                       "limit-exceeded", "/spp", WORK)
        assert body["detail"].startswith(f"this reference takes {3 * PIXELS} samples (pixels x spp), over max_work")
    finally:
        delete_all_sessions(small)


def test_sessions_boundary(small):
    try:
        for _ in range(SESSIONS):
            new_session(small, width=4, height=4)
        r = create(small, width=4, height=4)
        refused(r, 429, "too-many-sessions", None, SESSIONS)
        assert (r.header("Retry-After") or "").isdigit(), repr(r)
    finally:
        delete_all_sessions(small)


def test_upload_size_boundaries(small, tmp_path):
    # A JSON body of exactly max_json_body bytes is read; one byte more is refused unread.
    body = b'{"width": 4, "height": 4}'
    exact = body[:-1] + b" " * (JSON_BODY - len(body)) + b"}"
    assert len(exact) == JSON_BODY
    try:
        assert small.raw("POST", f"{CORNELL}/sessions", J, exact).status == 201
        refused(small.raw("POST", f"{CORNELL}/sessions", J, exact + b" "), 413, "body-too-large", None, JSON_BODY)
    finally:
        delete_all_sessions(small)
    ply = TETRA_PLY.replace(b"end_header\n", b"comment " + b"x" * (ASSET_BODY - len(TETRA_PLY) - 9) + b"\nend_header\n")
    assert len(ply) == ASSET_BODY
    ct = {"Content-Type": "model/ply"}
    assert small.raw("PUT", "/v1/scenes/lim-mesh/assets/tetra.ply", ct, ply).status == 201
    refused(small.raw("PUT", "/v1/scenes/lim-mesh/assets/big.ply", ct, ply + b"\n"), 413, "body-too-large", None,
            ASSET_BODY)
    exr = write_exr(tmp_path / "r.exr", np.full((4, 4, 3), 0.5, dtype="float32"), "none")
    assert len(exr) < REFERENCE_BODY
    ct = {"Content-Type": "image/x-exr"}
    assert small.raw("PUT", f"{CORNELL}/references/small", ct, exr).status == 201
    refused(small.raw("PUT", f"{CORNELL}/references/big", ct, exr + b"\0" * (REFERENCE_BODY + 1 - len(exr))), 413,
            "body-too-large", None, REFERENCE_BODY)


def planned_16x16(tmp_path):
    """The bytes a 16x16 session reserves, learnt from a daemon without a budget."""
    d = Daemon(tmp_path / "probe", *limits_args())
    try:
        planned = new_session(d, width=16, height=16)["reserved_bytes"]
    finally:
        d.stop()
    assert planned >= (2 + KEPT) * 16 * 16 * 12  # frame, accumulation and kept frames of float RGB
    return planned


def test_max_session_bytes_boundary(tmp_path):
    planned = planned_16x16(tmp_path)
    d = Daemon(tmp_path / "data", *limits_args(**{"--max-session-bytes": planned}))
    try:
        assert new_session(d, width=16, height=16)["reserved_bytes"] == planned
        refused(create(d, width=16, height=17), 422, "limit-exceeded", "", planned)
        assert d.req("GET", "/v1/limits").json()["max_session_bytes"] == planned
    finally:
        rc, _ = d.stop()
    assert rc == 0, d.stderr()[-3000:]


def test_max_session_bytes_names_restir_sms_light_reservoirs(tmp_path):
    """restir_sms keeps a reservoir per light by default: a session refused on its size says how
    many and which parameter asks for fewer, and asking for fewer fits."""
    slab = "/v1/scenes/refractive-slab"
    body = {"method": "restir_sms", "width": 16, "height": 16}
    probe = Daemon(tmp_path / "probe", *limits_args())
    try:
        one = probe.req("POST", f"{slab}/sessions", json_body={**body, "params": {"light_reservoirs": 1}}).json()
    finally:
        probe.stop()
    d = Daemon(tmp_path / "data", *limits_args(**{"--max-session-bytes": one["reserved_bytes"]}))
    try:
        r = refused(d.req("POST", f"{slab}/sessions", json_body=body), 422, "limit-exceeded", "",
                    one["reserved_bytes"])
        assert "2 reservoirs per pixel" in r["detail"] and "/params/light_reservoirs" in r["detail"], r
        ok = d.req("POST", f"{slab}/sessions", json_body={**body, "params": {"light_reservoirs": 1}})
        assert ok.status == 201, ok.body[:300]
    finally:
        rc, _ = d.stop()
    assert rc == 0, d.stderr()[-3000:]


def test_memory_budget_refuses_and_gives_back(tmp_path):
    planned = planned_16x16(tmp_path)
    budget = 2 * planned + 1000
    d = Daemon(tmp_path / "data", *limits_args(**{"--memory-budget": budget, "--job-workers": 1}))
    try:
        a, _ = new_session(d, width=16, height=16), new_session(d, width=16, height=16)
        used = d.req("GET", "/v1/limits").json()["memory_used"]
        assert used == {"sessions": 2 * planned, "scenes": 0, "references": 0, "uploads": 0}, used
        # Sessions, scenes and references all draw on the one budget.
        r = create(d, width=16, height=16)
        refused(r, 503, "memory-budget", None, budget)
        assert (r.header("Retry-After") or "").isdigit(), repr(r)
        r = d.req("PUT", "/v1/scenes/over-budget", json_body=cornell_scene(emission=[5, 5, 5]))
        refused(r, 503, "memory-budget", None, budget)
        assert_problem(d.req("GET", "/v1/scenes/over-budget"), 404, "scene-not-loaded")
        exr = write_exr(tmp_path / "r.exr", np.full((16, 16, 3), 0.5, dtype="float32"), "zip")
        r = d.raw("PUT", f"{CORNELL}/references/r", {"Content-Type": "image/x-exr"}, exr)
        refused(r, 503, "memory-budget", None, budget)
        # So does a reference job's result: the job fails, and its last event is that problem as
        # an `error`, with no `done` (so openapi.yaml's DoneEvent never says `failed`). The one job
        # worker has posted all of it once a second job has ended.
        def submit(name):
            r = d.req("POST", f"{a['href']}/references/{name}", json_body={"spp": SPP})
            assert r.status == 202, repr(r)
            return r.json()["id"]
        first = []

        def submit_two():
            first.append(submit("r-job"))
            return submit("r-job2")
        events = session_events(d, a["href"], submit_two)
        events = [(k, data) for k, data in events if isinstance(data, dict) and data.get("job") == first[0]]
        kind, data = events[-1]
        assert kind == "error" and data["type"] == P + "memory-budget" and data["status"] == 503, events
        assert "done" not in [k for k, _ in events], events
        job = d.req("GET", f"{a['href']}/renders/{data['job']}").json()
        assert job["status"] == "failed" and job["error"]["type"] == P + "memory-budget", job
        done = yaml.safe_load((ROOT / "protocol" / "openapi.yaml").read_text())["components"]["schemas"]["DoneEvent"]
        assert done["properties"]["status"]["enum"] == ["done", "cancelled"], done
        # A deleted session gives its bytes back: the refused requests now fit. The job worker
        # drops its hold on the session just after posting the job's last event (jobs.c,
        # jobs_worker), so on a loaded machine the bytes may come back a moment after the DELETE.
        assert d.req("DELETE", a["href"]).status == 204
        deadline = time.monotonic() + 10.0
        while (d.req("GET", "/v1/limits").json()["memory_used"]["sessions"] != planned
               and time.monotonic() < deadline):
            time.sleep(0.02)
        assert d.req("GET", "/v1/limits").json()["memory_used"]["sessions"] == planned
        r = d.req("PUT", "/v1/scenes/in-budget", json_body=cornell_scene(emission=[5, 5, 5]))
        assert r.status == 201, repr(r)
        scene_bytes = d.req("GET", "/v1/scenes/in-budget").json()["scene_bytes"]
        assert d.req("GET", "/v1/limits").json()["memory_used"]["scenes"] == scene_bytes
        assert d.raw("PUT", f"{CORNELL}/references/r", {"Content-Type": "image/x-exr"}, exr).status == 201
        assert d.req("GET", "/v1/limits").json()["memory_used"]["references"] == 16 * 16 * 12
        assert d.req("DELETE", "/v1/scenes/in-budget").status == 204
        assert d.req("GET", "/v1/limits").json()["memory_used"]["scenes"] == 0
    finally:
        rc, _ = d.stop()
    assert rc == 0, d.stderr()[-3000:]


def test_uploaded_scenes_charged_after_restart(tmp_path):
    data = tmp_path / "data"
    d = Daemon(data, *limits_args())
    try:
        assert put_mesh_scene(d, "keep").status == 201
        scene_bytes = d.req("GET", "/v1/scenes/keep").json()["scene_bytes"]
    finally:
        d.stop()
    # Restarted with a budget smaller than what is already on disk: nothing is dropped, the
    # bytes are charged, and new work is refused until room is made.
    d = Daemon(data, *limits_args(**{"--memory-budget": scene_bytes}))
    try:
        assert d.req("GET", "/v1/scenes/keep").status == 200
        assert d.req("GET", "/v1/limits").json()["memory_used"]["scenes"] == scene_bytes
        refused(create(d, width=4, height=4), 503, "memory-budget", None, scene_bytes)
    finally:
        rc, _ = d.stop()
    assert rc == 0, d.stderr()[-3000:]
