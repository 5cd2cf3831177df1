"""The benchmarks' child processes: a measurement is a function of a bench/
module, run in a fresh Python process by name, with a JSON spec in and a
JSON result out.

    result = harness.run_child("ab:measure", spec)            # in the parent
    python3 bench/harness.py MODULE:FUNCTION SPEC.json OUT.json   # the child

A fresh process per measurement makes peak memory and load times its own,
and keeps one variant and one build per process. The child's function gets
the spec (a dict) and returns a dict; it starts Mitsuba itself with
child_setup.mitsuba_for(variant, build). `home` gives the child its own HOME,
and so its own Dr.Jit kernel cache (~/.drjit): a cold cache, or one kept
apart from the user's. Mitsuba's log goes to the child's stdout (or, with
echo, to the parent's), and only the result file is read: no parsing of
printed lines (a child that counts Mitsuba's warnings does so with an
appender of its own: emission.py). stop_rss_gb stops a child whose memory
grows past a limit (step_memory.py).
"""
import importlib
import json
import os
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))


class ChildFailed(RuntimeError):
    """A child that exited with an error: its command, status and output.
    returncode: its exit status; stopped: killed by run_child's memory
    watchdog (stop_rss_gb); stderr: the end of its error output."""

    def __init__(self, message, returncode=None, stopped=False, stderr=""):
        super().__init__(message)
        self.returncode, self.stopped, self.stderr = returncode, stopped, stderr


def _rss(pid):
    """The resident set of process `pid` in bytes (0 once it is gone)"""
    try:
        with open(f"/proc/{pid}/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except OSError:
        return 0


def run_child(target, spec, home=None, timeout=None, stop_rss_gb=None, echo=False):
    """Runs `target` ("module:function" of bench/) on `spec` in a fresh
    process and returns its result (a dict). echo: the child's output goes
    to this process's, as it comes (progress of a long child), instead of
    into the error raised if it fails. stop_rss_gb: a watchdog that
    kills the child once its resident memory passes that many GB (the
    machine keeps its memory, no OOM killer), reported as ChildFailed with
    stopped=True."""
    with tempfile.TemporaryDirectory(prefix="nvdb-bench-") as tmp:
        spec_path, out_path = os.path.join(tmp, "spec.json"), os.path.join(tmp, "out.json")
        with open(spec_path, "w") as f:
            json.dump(spec, f)
        env = dict(os.environ)
        if home:
            os.makedirs(home, exist_ok=True)
            env["HOME"] = home
        cmd = [sys.executable, os.path.abspath(__file__), target, spec_path, out_path]
        # (output to files, not pipes: a child that prints much never blocks)
        with open(os.path.join(tmp, "stdout"), "w+") as out, \
                open(os.path.join(tmp, "stderr"), "w+") as err:
            child = subprocess.Popen(cmd, stdout=None if echo else out,
                                     stderr=None if echo else err, text=True, env=env)
            started, stopped = time.monotonic(), False
            while child.poll() is None:
                if stop_rss_gb is not None and _rss(child.pid) > stop_rss_gb * 1e9:
                    child.kill()
                    stopped = True
                if timeout is not None and time.monotonic() - started > timeout:
                    child.kill()
                    child.wait()
                    raise subprocess.TimeoutExpired(cmd, timeout)
                time.sleep(0.05)
            out.seek(0)
            err.seek(0)
            stdout, stderr = out.read(), err.read()
        if child.returncode != 0 or not os.path.exists(out_path):
            why = f"stopped at {stop_rss_gb:g} GB of RSS" if stopped else f"exit {child.returncode}"
            raise ChildFailed(f"{target} failed ({why}) on {spec}:\n{stdout[-4000:]}\n"
                              f"{stderr[-4000:]}", returncode=child.returncode,
                              stopped=stopped, stderr=stderr[-2000:])
        with open(out_path) as f:
            return json.load(f)


def _child(target, spec_path, out_path):
    sys.path.insert(0, HERE)
    module, function = target.split(":")
    with open(spec_path) as f:
        spec = json.load(f)
    result = getattr(importlib.import_module(module), function)(spec)
    with open(out_path, "w") as f:
        json.dump(result, f)


if __name__ == "__main__":
    if len(sys.argv) != 4:
        sys.exit(__doc__)
    _child(*sys.argv[1:])
