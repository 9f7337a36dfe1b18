"""tests/perf/instr_guard.sh's own failure paths: a render or callgrind that cannot be measured
exits 2 with the reason, never passes for a verdict on the budget; a missing valgrind says
SKIPPED. Fake binaries stand in for restir and valgrind, so this runs in well under a second."""
import json
import os
import subprocess
from pathlib import Path

GUARD = Path(__file__).resolve().parent / "instr_guard.sh"


def fake(tmp_path, name, body):
    path = tmp_path / name
    path.write_text("#!/bin/sh\n" + body + "\n")
    path.chmod(0o755)
    return str(path)


def guard(**env):
    return subprocess.run(["bash", str(GUARD)], capture_output=True, text=True, timeout=60,
                          env={**os.environ, **env})


def test_missing_valgrind_says_skipped(tmp_path):
    r = guard(VALGRIND=str(tmp_path / "no-valgrind"))
    assert r.returncode == 0
    assert "SKIPPED: valgrind missing" in r.stdout


def test_failing_render_cannot_be_measured(tmp_path):
    restir = fake(tmp_path, "restir", "echo 'scene: broken' >&2; exit 3")
    r = guard(RESTIR_BIN=restir, VALGRIND=fake(tmp_path, "valgrind", "exit 0"))
    assert r.returncode == 2, r.stderr
    assert "could not measure" in r.stderr and "status 3" in r.stderr and "scene: broken" in r.stderr


def test_same_ray_count_cannot_be_measured(tmp_path):
    restir = fake(tmp_path, "restir", "echo '{\"rays\": 5}'")
    r = guard(RESTIR_BIN=restir, VALGRIND=fake(tmp_path, "valgrind", "exit 0"))
    assert r.returncode == 2, r.stderr
    assert "no difference to divide by" in r.stderr


def test_no_callgrind_count_cannot_be_measured(tmp_path):
    # Ray counts that grow with --spp, and a "valgrind" that runs but prints no Collected line.
    restir = fake(tmp_path, "restir", 'for a; do [ "$p" = --spp ] && s=$a; p=$a; done; echo "{\\"rays\\": $s}"')
    valgrind = fake(tmp_path, "valgrind", "echo 'valgrind: unsupported' >&2; exit 0")
    r = guard(RESTIR_BIN=restir, VALGRIND=valgrind)
    assert r.returncode == 2, r.stderr
    assert "no 'Collected :' line" in r.stderr and "valgrind: unsupported" in r.stderr


def test_crashing_callgrind_cannot_be_measured(tmp_path):
    restir = fake(tmp_path, "restir", 'for a; do [ "$p" = --spp ] && s=$a; p=$a; done; echo "{\\"rays\\": $s}"')
    valgrind = fake(tmp_path, "valgrind", "echo 'Segmentation fault' >&2; exit 139")
    r = guard(RESTIR_BIN=restir, VALGRIND=valgrind)
    assert r.returncode == 2, r.stderr
    assert "status 139" in r.stderr


# A "valgrind" that counts 1000 instructions per ray, 400 of them in Embree's library: it prints
# the total and writes a callgrind profile with the two objects' own costs.
PROFILED = ('for a; do [ "$p" = --spp ] && s=$a; case $a in --callgrind-out-file=*) f=${a#*=};; esac; p=$a; done; '
            'printf "version: 1\\nevents: Ir\\nob=/usr/lib/libembree3.so.3\\nfl=???\\nfn=0x1\\n1 %d\\n'
            'ob=/bin/restir\\nfl=a.c\\nfn=main\\n1 %d\\n" $((s * 400)) $((s * 600)) > "$f"; '
            'echo "Collected : $((s * 1000))" >&2')


def test_unreadable_profile_cannot_be_measured(tmp_path):
    # The total is printed but no profile written: Embree's share cannot be read from it.
    restir = fake(tmp_path, "restir", 'for a; do [ "$p" = --spp ] && s=$a; p=$a; done; echo "{\\"rays\\": $s}"')
    valgrind = fake(tmp_path, "valgrind",
                    'for a; do [ "$p" = --spp ] && s=$a; p=$a; done; echo "Collected : $((s * 1000))" >&2')
    r = guard(RESTIR_BIN=restir, VALGRIND=valgrind)
    assert r.returncode == 2, r.stderr
    assert "callgrind_annotate could not read scenes/cornell-box/scene.json --spp 4's profile" in r.stderr


def test_budget_without_entry_cannot_be_measured(tmp_path):
    # Counts from fakes (1000 instructions per ray), a budget file that lacks the glossy render.
    restir = fake(tmp_path, "restir", 'for a; do [ "$p" = --spp ] && s=$a; p=$a; done; echo "{\\"rays\\": $s}"')
    valgrind = fake(tmp_path, "valgrind", PROFILED)
    budget = tmp_path / "budget.json"
    command = ("restir render scenes/cornell-box/scene.json --method pt --size 64x64 --threads 1 "
               "--max-depth 8 --frames 1 --params {\"sampler\":\"random\"} --spp {4,12}")
    budget.write_text(json.dumps({"tolerance": 0.02,
                                  "renders": {"diffuse": {"instr_per_ray": 1100, "command": command}}}))
    r = guard(RESTIR_BIN=restir, VALGRIND=valgrind, INSTR_BUDGET=str(budget))
    assert r.returncode == 2, r.stderr
    assert "pt diffuse, 1000.0 instructions per ray" in r.stdout
    assert "Embree 400.0, the rest 600.0" in r.stdout
    assert "NOTICE" in r.stdout and "to 1000.0" in r.stdout
    assert "no budget for /renders/glossy" in r.stderr
