"""The real daemon (build/restird, or $RESTIRD_BIN) as a child process, and HTTP plumbing to talk
to it: shared by the end-to-end tests (tests/test_daemon.py) and the cluster test
(tests/cluster/).

A daemon listens on an ephemeral loopback port (`--listen 127.0.0.1:0`; options given later
override it, so a restart can ask for the port it had) and names the port on its first stdout
line. Its stdout and stderr go to files beside its data directory."""
import http.client
import json
import os
import re
import signal
import socket
import subprocess
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
BIN = os.environ.get("RESTIRD_BIN", str(ROOT / "build" / "restird"))


class Resp:
    def __init__(self, status, headers, body):
        self.status, self.headers, self.body = status, headers, body

    def header(self, name, default=None):
        return self.headers.get(name, default)

    def json(self):
        return json.loads(self.body)

    def __repr__(self):
        hdrs = "".join(f"{k}: {v}\n" for k, v in self.headers.items())
        body = self.body[:600]
        return f"HTTP {self.status}\n{hdrs}\n{body!r}"


class Daemon:
    _starts = 0

    def __init__(self, data_dir, *extra, binary=BIN, env_extra=None, preexec_fn=None, wait_ready=True):
        Daemon._starts += 1
        self.data_dir = Path(data_dir)
        self.data_dir.mkdir(parents=True, exist_ok=True)
        logs = self.data_dir.parent / f"{self.data_dir.name}-log{Daemon._starts}"
        logs.mkdir(exist_ok=True)
        self.out_path, self.err_path = logs / "stdout", logs / "stderr"
        self.args = [str(binary), "--listen", "127.0.0.1:0", "--data-dir", str(self.data_dir), *map(str, extra)]
        with open(self.out_path, "wb") as out, open(self.err_path, "wb") as err:
            self.proc = subprocess.Popen(self.args, stdout=out, stderr=err, stdin=subprocess.DEVNULL,
                                         env={**os.environ, **(env_extra or {})}, preexec_fn=preexec_fn)
        deadline = time.monotonic() + 30
        self.port = None
        while time.monotonic() < deadline:
            first = self.out_path.read_bytes().split(b"\n", 1)
            if len(first) == 2:
                m = re.search(rb"restird listening on http://127\.0\.0\.1:(\d+)", first[0])
                assert m, f"unexpected first stdout line: {first[0]!r}"
                self.port = int(m.group(1))
                break
            if self.proc.poll() is not None:
                break
            time.sleep(0.02)
        if self.port is None:
            self.proc.kill()
            self.proc.wait()
            raise AssertionError(f"restird did not start: {self.args}\n{self.stderr()}")
        # It listens before its stored scenes are loaded; /readyz says when they are.
        while wait_ready and time.monotonic() < deadline and self.proc.poll() is None:
            try:
                if self.req("GET", "/readyz", timeout=5).status == 200:
                    break
            except OSError:
                pass
            time.sleep(0.02)

    def stderr(self):
        return self.err_path.read_text(errors="replace")

    def alive(self):
        return self.proc.poll() is None

    def stop(self, timeout=30):
        """SIGTERM; returns (exit code, seconds taken)."""
        t0 = time.monotonic()
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout=timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
                return None, time.monotonic() - t0
        return self.proc.returncode, time.monotonic() - t0

    def req(self, method, path, body=None, headers=None, json_body=None, timeout=120):
        headers = dict(headers or {})
        if json_body is not None:
            body = json.dumps(json_body).encode()
            headers.setdefault("Content-Type", "application/json")
        elif body is None and method in ("POST", "PUT"):
            # As the Python client does: an empty JSON body still declares its type (the daemon
            # requires it of every body route).
            headers.setdefault("Content-Type", "application/json")
        conn = http.client.HTTPConnection("127.0.0.1", self.port, timeout=timeout)
        try:
            conn.request(method, path, body=body, headers=headers)
            r = conn.getresponse()
            data = r.read()
            return Resp(r.status, r.headers, data)
        finally:
            conn.close()

    def raw(self, method, path, headers=None, body=b"", chunked=False, content_length="auto", timeout=30):
        """Sends a request byte by byte as given (no header is added but Host and, unless told
        otherwise, Content-Length), and parses the answer."""
        lines = [f"{method} {path} HTTP/1.1", "Host: 127.0.0.1"]
        lines += [f"{k}: {v}" for k, v in (headers or {}).items()]
        payload = body or b""
        if chunked:
            lines.append("Transfer-Encoding: chunked")
            payload = (b"%x\r\n" % len(body) + body + b"\r\n" if body else b"") + b"0\r\n\r\n"
        elif content_length == "auto":
            if body or method in ("POST", "PUT", "PATCH"):
                lines.append(f"Content-Length: {len(payload)}")
        elif content_length is not None:
            lines.append(f"Content-Length: {content_length}")
        data = ("\r\n".join(lines) + "\r\n\r\n").encode() + payload
        sock = socket.create_connection(("127.0.0.1", self.port), timeout=timeout)
        try:
            sock.sendall(data)
            r = http.client.HTTPResponse(sock, method=method)
            r.begin()
            return Resp(r.status, r.headers, r.read())
        finally:
            sock.close()
