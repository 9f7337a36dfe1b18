"""The image and the compose deployment, checked without a Docker engine (make test-cluster).

- docker/Dockerfile is linted: dockerlinter (npm, pinned in docker/lint/) with Debian's
  shellcheck on the RUN lines; a faulty copy must fail, so the linter is known to judge.
- The build stage's RUN lines run here as they are, from the repository root (the build
  context), in an environment without this make's variables: the image builds with the
  commands a developer runs, and they produce every file the runtime stage copies.
- The runtime stage's files are laid out in a temporary folder as the COPY lines place them,
  and the daemon is started with the image's ENTRYPOINT: it finds the scene library beside its
  binary, and the HEALTHCHECK command passes while it runs and fails once it has stopped.
- compose.yaml and haproxy.cfg agree on the daemons' names, port and data directory."""
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent.parent
sys.path.insert(0, str(ROOT / "tests"))
import dockerfile  # noqa: E402
from daemon import Daemon  # noqa: E402

DOCKER = ROOT / "docker"
DOCKERLINT = os.environ.get("DOCKERLINT", str(ROOT / "build" / "dockerlint" / "node_modules" / ".bin" / "dockerlinter"))
# Variables of the make that runs this test (SAN=1 among them) must not reach the image's make.
MAKE_VARS = ("MAKEFLAGS", "MFLAGS", "MAKELEVEL", "MAKEOVERRIDES", "SAN")


@pytest.fixture(scope="module")
def stages():
    parsed = dockerfile.parse(DOCKER / "Dockerfile")
    assert len(parsed) == 2, parsed
    return parsed


@pytest.fixture(scope="module")
def built(stages):
    """Runs the build stage's RUN lines in the repository root, as the image build does."""
    env = {k: v for k, v in os.environ.items() if k not in MAKE_VARS}
    for run in stages[0].all("RUN"):
        res = subprocess.run(["/bin/sh", "-c", run.args], cwd=ROOT, env=env, capture_output=True, text=True,
                             timeout=900)
        assert res.returncode == 0, f"{run}\n{res.stdout[-3000:]}\n{res.stderr[-3000:]}"
    return stages


def lint(path, cwd):
    # The linter writes each RUN line to a scratch file in its working folder for shellcheck.
    return subprocess.run([DOCKERLINT, "-f", str(path), "-e", "info"], cwd=cwd, capture_output=True, text=True,
                          timeout=120)


def listen_port(stage):
    args = stage.last("ENTRYPOINT").exec_form()
    return int(args[args.index("--listen") + 1].rsplit(":", 1)[1])


def test_dockerfile_lints_clean(tmp_path):
    r = lint(DOCKER / "Dockerfile", tmp_path)
    assert r.returncode == 0 and not r.stdout.strip(), r.stdout + r.stderr


def test_linter_finds_faults(tmp_path):
    bad = tmp_path / "Dockerfile"
    bad.write_text((DOCKER / "Dockerfile").read_text() + "RUN cd /tmp && echo $HOME\nUSER root\n")
    r = lint(bad, tmp_path)
    assert r.returncode == 1, r.stdout + r.stderr
    # SC2086 comes from shellcheck: the RUN lines really are checked.
    for rule in ("SC2086", "ER0003", "EU0001"):
        assert rule in r.stdout, r.stdout


def test_build_stage_is_the_developer_build(built):
    build, runtime = built
    assert build.image == "debian:bookworm" and build.name
    assert build.last("WORKDIR").args == "/src"
    assert [c.args for c in build.all("COPY")] == [". ."]
    commands = [c.strip() for run in build.all("RUN") for c in run.args.split("&&")]
    assert commands[0] == "bash scripts/install-deps.sh --build", commands
    assert re.fullmatch(r'make( -j"\$\(nproc\)")? DEPS=build', commands[1]), commands
    # Idempotent: with every package present it does nothing, and needs no network.
    again = subprocess.run(["bash", "scripts/install-deps.sh", "--build"], cwd=ROOT, capture_output=True, text=True,
                           timeout=120)
    assert again.returncode == 0 and not again.stdout and not again.stderr, again
    # The .dockerignore keeps the host's build folder and npm's packages out, so that make
    # starts from scratch and npm ci installs from the lockfile.
    ignored = (ROOT / ".dockerignore").read_text().split()
    assert "build" in ignored and "**/node_modules" in ignored, ignored
    copied = [(src, dest) for stage, src, dest in runtime.copies() if stage == build.name]
    assert copied
    for src, dest in copied:
        assert (ROOT / Path(src).relative_to("/src")).exists(), (src, dest)


def test_build_stage_installs_only_what_building_needs():
    """install-deps.sh --build names the compiler and the libraries the daemon links, and none
    of the tools that only tests and benchmarks use."""
    script = (ROOT / "scripts" / "install-deps.sh").read_text()
    build = re.search(r"^build_packages=\((.*?)^\)", script, re.S | re.M).group(1)
    names = set(re.sub(r"#[^\n]*", "", build).split())
    assert {"build-essential", "libembree-dev", "libmicrohttpd-dev", "nodejs"} <= names, names
    assert not names & {"chromium", "clang", "haproxy", "wrk", "embree-tools", "python3-pytest"}, names


def test_runtime_packages_hold_every_library_the_daemon_links(built):
    listed = dict(line.split("=", 1) for line in (ROOT / "build" / "runtime-packages.txt").read_text().split())
    assert "libmicrohttpd12" in listed and "libc6" not in listed, listed
    files = {}
    for name in [*listed, "libc6"]:
        res = subprocess.run(["dpkg-query", "-W", "-f=${Version}", name], capture_output=True, text=True)
        assert res.returncode == 0, res.stderr
        if name in listed:
            assert res.stdout == listed[name], (name, res.stdout, listed[name])
        out = subprocess.run(["dpkg", "-L", name], capture_output=True, text=True, check=True).stdout
        files[name] = {Path(p).name for p in out.split()}
    readelf = subprocess.run(["readelf", "-d", str(ROOT / "build" / "restird")], capture_output=True, text=True,
                             check=True).stdout
    needed = re.findall(r"Shared library: \[(.+)\]", readelf)
    assert "libembree3.so.3" in needed, needed
    for soname in needed:
        assert any(soname in names for names in files.values()), (soname, listed)


def test_runtime_stage_runs_the_daemon_as_laid_out(built, tmp_path):
    build, runtime = built
    assert runtime.image == "debian:bookworm-slim"
    user = runtime.last("USER").args
    assert user not in ("root", "0") and not user.startswith(("root:", "0:")), user
    useradd = [c for run in runtime.all("RUN") for c in run.args.split("&&") if "useradd" in c]
    assert len(useradd) == 1 and useradd[0].split()[-1] == user, useradd
    assert int(re.search(r"--uid (\d+)", useradd[0]).group(1)) > 0

    # The image's files, where its COPY lines put them.
    image = tmp_path / "image"
    for stage, src, dest in runtime.copies():
        if stage != build.name:
            continue
        source, target = ROOT / Path(src).relative_to("/src"), image / dest.lstrip("/")
        target.parent.mkdir(parents=True, exist_ok=True)
        if source.is_dir():
            shutil.copytree(source, target)
        else:
            shutil.copy2(source, target)

    port = listen_port(runtime)
    assert runtime.last("EXPOSE").args == str(port)
    entry = runtime.last("ENTRYPOINT").exec_form()
    data_dir = entry[entry.index("--data-dir") + 1]
    assert runtime.last("VOLUME").exec_form() == [data_dir]
    health = runtime.last("HEALTHCHECK").exec_form()
    assert health[0] == "bash" and health[2:] == [str(port)], health
    assert (image / health[1].lstrip("/")).is_file(), health

    # Options after the ENTRYPOINT's (docker run's CMD) override them: a loopback port here.
    d = Daemon(tmp_path / "data", *entry[1:], *runtime.last("CMD").exec_form(), "--id", "probe",
               "--listen", "127.0.0.1:0", "--data-dir", tmp_path / "data", binary=image / entry[0].lstrip("/"))
    try:
        r = d.req("GET", "/v1/scenes")
        assert r.status == 200 and r.header("X-Served-By") == "probe", repr(r)
        library = {p.parent.name for p in (ROOT / "scenes").glob("*/scene.json")}
        assert library and library <= {s["id"] for s in r.json()["scenes"]}, r.json()
        check = [health[0], str(image / health[1].lstrip("/")), str(d.port)]
        res = subprocess.run(check, capture_output=True, text=True, timeout=30)
        assert res.returncode == 0, res.stderr
    finally:
        rc, _ = d.stop()
    assert rc == 0, d.stderr()[-3000:]
    res = subprocess.run(check, capture_output=True, text=True, timeout=30)
    assert res.returncode != 0, "the health check passed with the daemon stopped"

    # Started as the image starts it (0.0.0.0) without a token, it refuses before binding.
    env = {k: v for k, v in os.environ.items() if k != "RESTIRD_AUTH_TOKEN"}
    res = subprocess.run([str(image / entry[0].lstrip("/")), *entry[1:], "--data-dir", str(tmp_path / "refused")],
                         env=env, capture_output=True, text=True, timeout=30, stdin=subprocess.DEVNULL)
    assert res.returncode == 1 and "0.0.0.0 (beyond loopback) needs a bearer token" in res.stderr, res
    assert not (tmp_path / "refused").exists()


def test_compose_and_haproxy_agree(stages):
    runtime = stages[-1]
    port = listen_port(runtime)
    entry = runtime.last("ENTRYPOINT").exec_form()
    data_dir = entry[entry.index("--data-dir") + 1]
    compose = yaml.safe_load((DOCKER / "compose.yaml").read_text())
    services = compose["services"]
    daemons = sorted(name for name in services if name != "haproxy")
    assert daemons == ["restird-0", "restird-1", "restird-2"], daemons
    for name in daemons:
        s = services[name]
        assert (DOCKER / s["build"]["context"]).resolve() == ROOT and s["build"]["dockerfile"] == "docker/Dockerfile"
        assert s["command"] == ["--id", name], s
        # They listen on 0.0.0.0: compose passes them the token, and refuses to start without one.
        assert s["environment"]["RESTIRD_AUTH_TOKEN"].startswith("${RESTIRD_AUTH_TOKEN:?"), s
        assert [v.split(":", 1)[1] for v in s["volumes"]] == [data_dir], s

    cfg = (DOCKER / "haproxy.cfg").read_text()
    # The server addresses default to the compose services, on the daemons' port.
    servers = re.findall(r'^\s*server (\S+) "\$\{(\w+)-([^}]+)\}"', cfg, re.M)
    assert [(n, addr) for n, _, addr in servers] == [(d, f"{d}:{port}") for d in daemons], servers
    for directive in ("balance uri depth 3", "hash-type consistent", "option httpchk GET /readyz"):
        assert re.search(rf"^\s*{re.escape(directive)}\s*$", cfg, re.M), directive
    bind = re.search(r'^\s*bind "\$\{\w+-:(\d+)\}"', cfg, re.M)
    proxy = services["haproxy"]
    assert bind and [p.rsplit(":", 1)[1] for p in proxy["ports"]] == [bind.group(1)], proxy["ports"]
    assert "./haproxy.cfg:/usr/local/etc/haproxy/haproxy.cfg:ro" in proxy["volumes"]
    assert proxy["depends_on"] == {d: {"condition": "service_healthy"} for d in daemons}
