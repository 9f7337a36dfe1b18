"""CPU time of a child process: user + system seconds of its whole process tree (its threads and
the processes it waits for), from the difference of getrusage(RUSAGE_CHILDREN) around the run.
CPU seconds rather than wall time, because this machine is shared (docs/benchmarks.md)."""
import resource
import subprocess


def run_timed(cmd):
    """Runs cmd (capturing its output as text); returns (the completed process, its CPU seconds)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    res = subprocess.run([str(c) for c in cmd], capture_output=True, text=True)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return res, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
