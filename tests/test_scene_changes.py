"""Camera and light changes sent with a frame request are exact: a frame rendered after a change
is bit-identical to the same frame of a scene file that has the change written into it, and the
change stays in force for later frames. These pin down renderer/session/view.c and scene_derive in
renderer/scene/scene.c (derived scenes share geometry with the loaded one) through the daemon."""
import copy
import http.client
import json
import os
import re
import signal
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import pytest

ROOT = Path(__file__).resolve().parent.parent
BIN = os.environ.get("RESTIRD_BIN", str(ROOT / "build" / "restird"))
CORNELL = json.loads((ROOT / "scenes" / "cornell-box" / "scene.json").read_text())


@pytest.fixture(scope="module")
def daemon(tmp_path_factory):
    data = tmp_path_factory.mktemp("data")
    proc = subprocess.Popen([BIN, "--listen", "127.0.0.1:0", "--data-dir", str(data), "--threads", "2"],
                            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    line = proc.stdout.readline()
    m = re.search(r"127\.0\.0\.1:(\d+)", line)
    assert m, line
    yield int(m.group(1))
    proc.send_signal(signal.SIGTERM)
    assert proc.wait(timeout=60) == 0


def call(port, method, path, body=None, accept="application/json", ctype="application/json"):
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=120)
    data = json.dumps(body).encode() if body is not None else None
    headers = {"Accept": accept}
    if data is not None or method in ("POST", "PUT"):
        headers["Content-Type"] = ctype
    conn.request(method, path, body=data, headers=headers)
    r = conn.getresponse()
    payload = r.read()
    conn.close()
    return r.status, dict(r.getheaders()), payload


def exr_pixels(data):
    """Decodes an EXR answer with OpenImageIO (an independent reader)."""
    with tempfile.NamedTemporaryFile(suffix=".exr") as f:
        f.write(data)
        f.flush()
        inp = oiio.ImageInput.open(f.name)
        px = inp.read_image(oiio.FLOAT)
        inp.close()
    return np.asarray(px, dtype=np.float32)[:, :, :3]


def session(port, scene, spp=2, seed=7, size=24):
    st, hdr, body = call(port, "POST", f"/v1/scenes/{scene}/sessions",
                         {"width": size, "height": size, "seed": seed, "params": {"spp": spp}})
    assert st == 201, body
    return hdr["Location"]


def frame(port, sess, body=None):
    st, hdr, data = call(port, "POST", sess + "/frames", body, accept="image/x-exr")
    assert st == 200, data
    return exr_pixels(data)


def put_scene(port, sid, scene):
    st, _, body = call(port, "PUT", f"/v1/scenes/{sid}", scene)
    assert st in (200, 201), body


def light_index():
    return next(i for i, s in enumerate(CORNELL["shapes"]) if s.get("name") == "ceiling_light")


def test_moved_light_matches_scene_with_light_moved(daemon):
    moved = copy.deepcopy(CORNELL)
    moved["shapes"][light_index()]["transform"] = {"translate": [-60, -120, 40]}
    put_scene(daemon, "cb-light-moved", moved)
    a = session(daemon, "cornell-box")
    b = session(daemon, "cb-light-moved")
    fa0 = frame(daemon, a, {"lights": {"ceiling_light": {"position": [-60, -120, 40]}}})
    fb0 = frame(daemon, b)
    assert np.array_equal(fa0, fb0)
    # The change stays in force: the next frame (no body) still matches.
    assert np.array_equal(frame(daemon, a), frame(daemon, b))
    # And the image did change against the original light position.
    c = session(daemon, "cornell-box")
    assert not np.array_equal(frame(daemon, c), fa0)


def test_camera_change_matches_scene_with_that_camera(daemon):
    cam = {"position": [400, 300, -700], "look_at": [250, 250, 250], "up": [0, 1, 0], "fov_deg": 45}
    other = copy.deepcopy(CORNELL)
    other["camera"].update(cam)
    put_scene(daemon, "cb-camera", other)
    a = session(daemon, "cornell-box")
    b = session(daemon, "cb-camera")
    assert np.array_equal(frame(daemon, a, {"camera": cam}), frame(daemon, b))


def test_doubled_emission_doubles_every_pixel_exactly(daemon):
    # Doubling the only emitter leaves the light-selection probabilities unchanged, and a
    # multiplication by 2 is exact in floating point, so every sample (and sum) doubles exactly.
    light_mat = CORNELL["shapes"][light_index()]["material"]
    e = CORNELL["materials"][light_mat]["emission"]
    a = session(daemon, "cornell-box")
    b = session(daemon, "cornell-box")
    fa = frame(daemon, a)
    fb = frame(daemon, b, {"lights": {"ceiling_light": {"emission": [2 * x for x in e]}}})
    assert fa.mean() > 0
    assert np.array_equal(fb, 2 * fa)


def test_light_switched_off_gives_black_and_back_on_restores(daemon):
    light_mat = CORNELL["shapes"][light_index()]["material"]
    e = CORNELL["materials"][light_mat]["emission"]
    a = session(daemon, "cornell-box")
    ref = session(daemon, "cornell-box")
    off = frame(daemon, a, {"lights": {"ceiling_light": {"emission": [0, 0, 0]}}})
    assert np.all(off == 0)
    frame(daemon, ref)
    # Frame 1 of both: back on must equal the untouched session's frame 1.
    on = frame(daemon, a, {"lights": {"ceiling_light": {"emission": e}}})
    assert np.array_equal(on, frame(daemon, ref))


def test_accumulation_restarts_on_change(daemon):
    a = session(daemon, "cornell-box")
    for _ in range(3):
        frame(daemon, a)
    st, hdr, body = call(daemon, "GET", a + "/accumulation")
    assert st == 200 and json.loads(body)["frames"] == 3
    frame(daemon, a, {"camera": {"fov_deg": 30}})
    st, hdr, body = call(daemon, "GET", a + "/accumulation")
    assert st == 200 and json.loads(body)["frames"] == 1


def test_change_naming_unknown_shape_leaves_session_unchanged(daemon):
    a = session(daemon, "cornell-box")
    b = session(daemon, "cornell-box")
    st, _, body = call(daemon, "POST", a + "/frames", {"lights": {"no_such_light": {"emission": [1, 1, 1]}}})
    p = json.loads(body)
    assert st == 422 and p["field"] == "/lights/no_such_light", body
    # The refused request rendered nothing: frame 0 of a equals frame 0 of b.
    assert np.array_equal(frame(daemon, a), frame(daemon, b))


def test_camera_merged_with_session_camera_is_validated(daemon):
    # Each member is valid alone; merged with the session's camera (looking along +z), an up of
    # +z is parallel to the view direction: refused at /camera, and nothing is rendered.
    a = session(daemon, "cornell-box")
    st, _, body = call(daemon, "POST", a + "/frames", {"camera": {"up": [0, 0, 1]}})
    p = json.loads(body)
    assert st == 422 and p["field"] == "/camera" and "parallel" in p["detail"], body
    st, _, body = call(daemon, "GET", a)
    assert json.loads(body)["frames_rendered"] == 0


CLI = os.environ.get("RESTIR_BIN", str(ROOT / "build" / "restir"))


def cli_render(tmp_path, *args):
    """`restir render` of the Cornell box: pt at 2 spp, or the --method in args (the methods
    other than pt here take no spp and refuse --spp)."""
    out = tmp_path / "cli.exr"
    spp = [] if "--method" in args else ["--spp", "2"]
    res = subprocess.run([CLI, "render", str(ROOT / "scenes" / "cornell-box" / "scene.json"), "--size", "24x24",
                          *spp, "--seed", "7", "--threads", "2", "-o", str(out), *map(str, args)],
                         capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    return exr_pixels(out.read_bytes())


def test_cli_frames_match_daemon_session(daemon, tmp_path):
    # `restir render --frames 4` is a session without the server: its last frame is frame 3 of
    # a daemon session with the same seed and parameters, bit for bit.
    a = session(daemon, "cornell-box")
    for _ in range(3):
        frame(daemon, a)
    assert np.array_equal(cli_render(tmp_path, "--frames", 4), frame(daemon, a))


def test_cli_restir_pt_matches_daemon_defaults(daemon, tmp_path):
    # `restir render --method restir_pt` without --params or --rr-depth is a daemon restir_pt
    # session with its defaults; --rr-depth reaches it only when given (then it is the session
    # param rr_depth). The CLI's own --rr-depth default (3, pt's) once leaked into restir_pt.
    def restir_session(params):
        st, hdr, body = call(daemon, "POST", "/v1/scenes/cornell-box/sessions",
                             {"method": "restir_pt", "width": 24, "height": 24, "seed": 7, "params": params})
        assert st == 201, body
        s = hdr["Location"]
        for _ in range(2):
            frame(daemon, s)
        return frame(daemon, s)

    default = cli_render(tmp_path, "--method", "restir_pt", "--frames", 3)
    assert np.array_equal(default, restir_session({}))
    third = cli_render(tmp_path, "--method", "restir_pt", "--frames", 3, "--rr-depth", 3)
    assert np.array_equal(third, restir_session({"rr_depth": 3}))
    assert not np.array_equal(default, third)


def test_cli_animation_matches_daemon_job(daemon, tmp_path):
    body = {"animation": {"fps": 10, "frames": 3, "interpolation": "catmull_rom",
                          "camera_keys": [{"t": 0, "position": [278, 273, -800]},
                                          {"t": 0.2, "position": [330, 280, -760], "fov_deg": 35}],
                          "light_keys": {"ceiling_light": [{"t": 0, "emission": [17, 12, 4]},
                                                           {"t": 0.2, "emission": [4, 12, 17],
                                                            "position": [0, -30, 0]}]}}}
    anim = tmp_path / "anim.json"
    anim.write_text(json.dumps(body))
    a = session(daemon, "cornell-box")
    st, hdr, data = call(daemon, "POST", a + "/renders", body)
    assert st == 202, data
    job = hdr["Location"]
    for _ in range(600):
        st, _, data = call(daemon, "GET", job)
        if json.loads(data)["status"] in ("done", "failed", "cancelled"):
            break
        time.sleep(0.05)
    assert json.loads(data)["status"] == "done", data
    st, _, last = call(daemon, "GET", a + "/frames/2", accept="image/x-exr")
    assert st == 200
    assert np.array_equal(cli_render(tmp_path, "--animation", anim), exr_pixels(last))


def test_cli_animation_errors_name_the_key(tmp_path):
    anim = tmp_path / "bad.json"
    anim.write_text(json.dumps({"animation": {"frames": 2, "light_keys": {"no_such": [{"t": 0, "emission": [1, 1, 1]}]}}}))
    res = subprocess.run([CLI, "render", str(ROOT / "scenes" / "cornell-box" / "scene.json"), "--size", "8x8",
                          "--animation", str(anim), "-o", str(tmp_path / "x.exr")], capture_output=True, text=True)
    assert res.returncode == 1 and "/animation/light_keys/no_such" in res.stderr, res.stderr
    res = subprocess.run([CLI, "render", str(ROOT / "scenes" / "cornell-box" / "scene.json"), "--frames", "2",
                          "--crop", "0,0,4,4", "-o", str(tmp_path / "x.exr")], capture_output=True, text=True)
    assert res.returncode == 2 and "--crop" in res.stderr, res.stderr
