"""Every fenced code block of the user-facing documents runs verbatim.

The rule, by the language named after the opening fence:

  sh, bash  run by bash, line by line as written
  python    run by python3
  shell     shell commands for another machine (a Docker host, a daemon on a public address,
            a cluster): shown, never run here, but held to the curl rule below as run blocks are
  json, text, yaml, csv, http, c, mjs  shown, never run (bodies, output, listings, synopses)

A block with no language, or one not listed, fails the test: each block says which kind it is.

The blocks of one document run in order as one bash script (`set -eo pipefail`; a python block is
fed to `python3 -` inside it), in one temporary directory that mirrors the checkout (symlinks to
its entries, but a copy of clients/python, where pip builds; build/restir and build/restird are
the binaries under test), so a block sees the variables and files of the blocks before it and
writes nothing into the checkout (the files git does not track are compared before and after). A
block fails the test when a command in it exits non-zero; every curl in a run block must carry
-f, so an HTTP error answer fails it too rather than landing in an output file; and a block waits
only in counted for loops (no while or until), so an example whose wait never ends fails rather
than hanging. A document's blocks have TIMEOUT seconds together; the failure names the block
that failed or was running when they ran out.

The daemon runs as `make run` starts it, on 127.0.0.1:8080 with a default session on
cornell-box (its data directory in the temporary directory), because that is the address the
documents give. Each document has a daemon of its own, started afresh, so the sessions,
references and uploads one leaves behind are not seen by the next, and a document run alone
(-k) runs as it does among the others. When 8080 is taken the test is skipped with that
reason, or fails when $CI is set: a CI machine has the port free.

Blocks that would run more than an example are left out, whole, for the reason in SKIP."""
import os
import re
import socket
import shutil
import signal
import subprocess
from pathlib import Path

import pytest

from daemon import Daemon, ROOT

DOCUMENTS = ["README.md", "protocol/API.md", "clients/python/README.md", "docs/deploy.md"]
RUN = {"sh", "bash", "python"}
SHOWN = {"shell", "json", "text", "yaml", "csv", "http", "c", "mjs"}
# A block holding one of these make targets is not run: (target pattern, reason). A block left out
# must hold nothing else (but comments), or the rest of it would go untested unnoticed.
SKIP = [
    (r"run", "starts the daemon on 8080, which this test has started already"),
    (r"test\S*", "runs a test suite; `make test` runs this test too"),
    (r"bench\S*", "benchmarks take minutes to hours"),
]
PORT = 8080
TIMEOUT = 120  # seconds a document's blocks may take together
FENCE = re.compile(r"^(\s*)(`{3,})(.*)$")


def blocks(path):
    """[(line number of the opening fence, language, text)] of the Markdown file, in order."""
    out, lines, i = [], path.read_text().splitlines(), 0
    while i < len(lines):
        m = FENCE.match(lines[i])
        if not m:
            i += 1
            continue
        indent, ticks, info = m.group(1), m.group(2), m.group(3).strip()
        start, body, i = i + 1, [], i + 1
        while i < len(lines) and not (lines[i].strip().startswith(ticks) and lines[i].strip().strip("`") == ""):
            body.append(lines[i][len(indent):] if lines[i].startswith(indent) else lines[i].lstrip())
            i += 1
        out.append((start, info.split()[0] if info else "", "\n".join(body) + "\n"))
        i += 1
    return out


def skipped_target(cmd):
    """'make TARGET: reason' when the command line is a make run of a target in SKIP, else None."""
    words = cmd.split()
    if words[:1] != ["make"]:
        return None
    for word in words[1:]:
        if "=" in word or word.startswith("-"):
            continue  # VAR=value or an option
        for pattern, why in SKIP:
            if re.fullmatch(pattern, word):
                return f"make {word}: {why}"
    return None


def skip_reason(text):
    """Why the block is left out (None: it runs); AssertionError when it holds a target to leave
    out beside another command."""
    cmds = [c for c in (line.split("#", 1)[0].strip() for line in text.splitlines()) if c]
    reasons = [r for r in map(skipped_target, cmds) if r]
    others = [c for c in cmds if not skipped_target(c)]
    assert not (reasons and others), f"a block left out ({reasons[0]}) holds other commands: {others}"
    return reasons[0] if reasons else None


def unbounded_loops(text):
    """The while/until lines of a block: an example waits with a counted for loop, so a wait for
    something that never comes ends the example instead of hanging it."""
    return [line.strip() for line in text.splitlines() if re.match(r"\s*(?:while|until)\b", line)]


def curls_without_f(text):
    """The curl command lines of a block that do not fail on an HTTP error (-f / --fail)."""
    bad = []
    for line in text.replace("\\\n", " ").splitlines():
        for cmd in re.findall(r"\bcurl\b([^|;&)]*)", line):
            if not re.search(r"(?:^|\s)(?:--fail(?:-with-body)?|-[a-zA-Z]*f[a-zA-Z]*)(?=\s|$)", cmd):
                bad.append(("curl" + cmd).strip())
    return bad


def script(doc):
    """The bash script that runs doc's blocks in order, and the blocks it leaves out."""
    parts, skipped = ["set -eo pipefail"], []
    for line, lang, text in blocks(ROOT / doc):
        where = f"{doc}:{line}"
        assert lang in RUN | SHOWN, f"{where}: a fenced block needs a language, one of {sorted(RUN | SHOWN)}"
        if lang in RUN | {"shell"}:
            assert not curls_without_f(text), f"{where}: curl without -f: {curls_without_f(text)}"
        if lang not in RUN:
            continue
        try:
            reason = skip_reason(text)
        except AssertionError as e:
            raise AssertionError(f"{where}: {e}") from None
        if reason:
            skipped.append(f"{where}: {reason}")
            continue
        assert not unbounded_loops(text), f"{where}: a loop with no bound: {unbounded_loops(text)}"
        parts.append(f"echo '=== {where} ({lang})' >&2")
        if lang == "python":
            parts.append(f"python3 - <<'__EXAMPLE_END__'\n{text}__EXAMPLE_END__")
        else:
            parts.append(text)
    return "\n".join(parts) + "\n", skipped


def test_every_document_block_is_labelled_and_curl_fails_on_http_errors():
    """Runs without a daemon, so a missing label or -f is reported even where 8080 is taken."""
    for doc in DOCUMENTS:
        script(doc)


def test_skip_rule_and_curl_rule_judge():
    assert skip_reason("make run   # starts it\n").startswith("make run:")
    assert skip_reason("make -j2\nbuild/restir --help\n") is None
    assert skip_reason("make test-web\n").startswith("make test-web:")
    assert skip_reason("make SAN=1 test-perf   # under ASan\n").startswith("make test-perf:")
    assert skip_reason("make bench-report QUICK=1\n").startswith("make bench-report:")
    with pytest.raises(AssertionError, match="holds other commands"):
        skip_reason("make run\ncurl -fsS http://h/\n")
    assert unbounded_loops("until curl -fsS http://h/; do sleep 1; done\n") == ["until curl -fsS http://h/; do sleep 1; done"]
    assert unbounded_loops("for i in $(seq 9); do sleep 1; done  # while it runs\n") == []
    assert curls_without_f("X=$(curl -s -o x http://h/ | jq)\n") == ["curl -s -o x http://h/"]
    assert curls_without_f("curl -fsS -X POST \\\n  http://h/\ncurl --fail http://h/\n") == []


@pytest.fixture
def daemon(tmp_path):
    with socket.socket() as s:
        # As the daemon binds: connections of an earlier run waiting out TIME_WAIT do not count.
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind(("127.0.0.1", PORT))
        except OSError as e:
            message = f"127.0.0.1:{PORT} is taken ({e}); the documented examples need the daemon there"
            if os.environ.get("CI"):
                pytest.fail(message)
            pytest.skip(message)
    d = Daemon(tmp_path / "data", "--listen", f"127.0.0.1:{PORT}",
               "--default-session", "cornell-box")
    yield d
    d.stop()


# Entries of the checkout the examples build in (pip writes build/ and *.egg-info beside the
# package it installs), so the mirror holds a copy of them rather than a link.
COPIED = {Path("clients/python")}


def mirror(tmp_path, src=ROOT):
    """A directory that looks like the checkout: its entries linked (the ones in COPIED copied),
    build/ holding the binaries under test."""
    tmp_path.mkdir(exist_ok=True)
    for entry in src.iterdir():
        rel, dst = entry.relative_to(ROOT), tmp_path / entry.name
        if rel in (Path("build"), Path(".git")):
            continue
        if rel in COPIED:
            shutil.copytree(entry, dst, symlinks=True,
                            ignore=shutil.ignore_patterns("build", "*.egg-info", "__pycache__"))
        elif any(rel in c.parents for c in COPIED):
            dst.mkdir()
            mirror(dst, entry)
        else:
            dst.symlink_to(entry)
    if src == ROOT:
        (tmp_path / "build").mkdir()
        for name, env in (("restir", "RESTIR_BIN"), ("restird", "RESTIRD_BIN")):
            (tmp_path / "build" / name).symlink_to(os.environ.get(env, str(ROOT / "build" / name)))
    return tmp_path


def checkout_files():
    """The checkout's files that git does not track (ignored ones too), but for build/, where
    the binaries and other tests write: None outside a git checkout."""
    res = subprocess.run(["git", "status", "--porcelain", "--ignored", "--untracked-files=all"],
                         cwd=ROOT, capture_output=True, text=True)
    if res.returncode != 0:
        return None
    return {line for line in res.stdout.splitlines()
            if not line[3:].startswith("build/") and "/node_modules/" not in line}


def run_script(doc, text, cwd, env, timeout):
    """Runs a document's script; None when it succeeds, else what failed: the block (the last
    '===' line it wrote) and the tail of its output."""
    proc = subprocess.Popen(["bash", "-c", text], cwd=cwd, env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        out, err = proc.communicate(timeout=timeout)
        if proc.returncode == 0:
            return None
        what = f"failed (exit {proc.returncode})"
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)  # the block's commands with it, so the pipes close
        out, err = proc.communicate()
        what = f"did not end within {timeout} s"
    started = re.findall(r"^=== (.*)$", err, re.M)
    block = started[-1] if started else f"{doc}, before its first block"
    return f"{block}: {what}\n{err[-4000:]}\n{out[-2000:]}"


def test_a_failing_or_hanging_block_is_named():
    env = {"PATH": os.environ.get("PATH", "/usr/bin")}
    hang = "echo '=== X.md:3 (sh)' >&2; echo waiting >&2; sleep 60\n"
    failure = run_script("X.md", hang, ROOT, env, 0.5)
    assert failure.startswith("X.md:3 (sh): did not end within 0.5 s") and "waiting" in failure, failure
    failure = run_script("X.md", "echo '=== X.md:9 (sh)' >&2; false\n", ROOT, env, 10)
    assert failure.startswith("X.md:9 (sh): failed (exit 1)"), failure
    assert run_script("X.md", "true\n", ROOT, env, 10) is None


@pytest.mark.parametrize("doc", DOCUMENTS)
def test_examples_run_verbatim(doc, daemon, tmp_path):
    text, skipped = script(doc)
    # The daemon as `make run` starts it, whatever documents ran before.
    sessions = daemon.req("GET", "/v1/scenes/cornell-box/sessions").json()["sessions"]
    references = daemon.req("GET", "/v1/scenes/cornell-box/references").json()["references"]
    assert ([x["id"] for x in sessions], references) == (["default"], [])
    before = checkout_files()
    print("left out:", *skipped, sep="\n  ")
    env = {**os.environ, "PATH": "/usr/bin:" + os.environ.get("PATH", "")}
    for var in ("RESTIRD_URL", "RESTIRD_AUTH_TOKEN"):
        env.pop(var, None)
    failure = run_script(doc, text, mirror(tmp_path / "checkout"), env, TIMEOUT)
    assert failure is None, failure
    assert daemon.alive(), daemon.stderr()
    after = checkout_files()
    assert after is None or after <= before, f"{doc}: the examples wrote into the checkout: {sorted(after - before)}"
