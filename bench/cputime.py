"""CPU time of a child process: user + system seconds of its whole process tree (its threads and
the processes it waits for), from the difference of getrusage(RUSAGE_CHILDREN) around the run;
a daemon frame's CPU time over its threads (frame_time_ms), and the same of a `restir render --json`
summary (cli_frame_ms). CPU seconds rather than wall time,
because this machine is shared (docs/benchmarks.md). And the report's progress lines, stamped with
the wall-clock minutes since the run began (progress). Stdlib only."""
import resource
import subprocess
import sys
import time

# When the run began: the first import of this module, at the start of any bench script.
RUN_T0 = time.monotonic()


def progress(msg):
    """One line of the report's log on stderr, ending with the minutes since the run began, so a
    long run's log shows where its time went."""
    print(f"report: {msg} [{(time.monotonic() - RUN_T0) / 60:.1f} min]", file=sys.stderr, flush=True)


def run_timed(cmd):
    """Runs cmd (capturing its output as text); returns (the completed process, its CPU seconds)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    res = subprocess.run([str(c) for c in cmd], capture_output=True, text=True)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return res, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def frame_time_ms(frame):
    """A frame's time from its JSON: the CPU time of all its threads over their number
    (render_cpu_ms / threads), which is its wall time with every thread busy and nothing else on
    the machine, and which other work on a shared machine stretches far less than the wall clock
    (docs/benchmarks.md, "Two regimes"); render_ms, the wall time, from a daemon that does not
    report CPU time."""
    cpu = frame.get("render_cpu_ms")
    return _per_thread(cpu, frame) if cpu is not None else frame["render_ms"]


def cli_frame_ms(summary, frames=1, last_frame=False):
    """A frame's time from this checkout's `restir render --json` summary, by CPU as
    frame_time_ms: the session's cpu_ms over its threads and its `frames`; with last_frame, the
    last frame's own (last_frame_cpu_ms: the frame after a warm-up, alone)."""
    if last_frame:
        return _per_thread(summary["last_frame_cpu_ms"], summary)
    return _per_thread(summary["cpu_ms"], summary) / frames


def _per_thread(cpu_ms, stats):
    """CPU milliseconds over the threads that spent them (the wall time with all of them busy)."""
    return cpu_ms / max(1, stats.get("threads") or 1)
