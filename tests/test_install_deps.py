"""scripts/install-deps.sh's arguments, against stand-ins for dpkg-query and apt-get: nothing is
installed and nothing goes to the network."""
import os
import subprocess

from conftest import ROOT

SCRIPT = ROOT / "scripts" / "install-deps.sh"


def install(tmp_path, *args):
    """Runs the script with every package reported missing; returns (exit status, stderr, the
    packages apt-get install was given)."""
    stubs = tmp_path / "bin"
    stubs.mkdir(exist_ok=True)
    log = tmp_path / "apt.log"
    log.write_text("")
    for name, body in {"dpkg-query": "exit 1",
                       "apt-get": f'[ "$1" = install ] && printf "%s\\n" "$@" >> {log}; exit 0',
                       "sudo": 'exec "$@"'}.items():
        (stubs / name).write_text(f"#!/bin/sh\n{body}\n")
        (stubs / name).chmod(0o755)
    env = {**os.environ, "PATH": f"{stubs}:{os.environ['PATH']}"}
    res = subprocess.run(["bash", SCRIPT, *args], capture_output=True, text=True, env=env, timeout=60)
    return res.returncode, res.stderr, set(log.read_text().split()) - {"install", "-y", "-qq", "--no-install-recommends"}


def test_build_is_an_option_anywhere_among_the_packages(tmp_path):
    first = install(tmp_path, "--build", "blender")
    last = install(tmp_path, "blender", "--build")
    assert first[0] == last[0] == 0, (first, last)
    assert first[2] == last[2] and "blender" in last[2] and "--build" not in last[2], last
    assert "libembree-dev" in last[2] and "chromium" not in last[2], last
    assert "chromium" in install(tmp_path, "blender")[2]


def test_an_unknown_option_is_refused_before_apt(tmp_path):
    status, stderr, apt = install(tmp_path, "blender", "--yes")
    assert status == 2 and "unknown option '--yes'" in stderr and not apt, (status, stderr, apt)
