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
apart from the user's. Mitsuba's log goes to the child's stdout, and only
the result file is read: no parsing of printed lines.
"""
import importlib
import json
import os
import subprocess
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))


class ChildFailed(RuntimeError):
    """A child that exited with an error: its command, status and output"""


def run_child(target, spec, home=None, timeout=None):
    """Runs `target` ("module:function" of bench/) on `spec` in a fresh
    process and returns its result (a dict)."""
    with tempfile.TemporaryDirectory(prefix="nvdb-bench-") as tmp:
        spec_path, out_path = os.path.join(tmp, "spec.json"), os.path.join(tmp, "out.json")
        with open(spec_path, "w") as f:
            json.dump(spec, f)
        env = dict(os.environ)
        if home:
            os.makedirs(home, exist_ok=True)
            env["HOME"] = home
        p = subprocess.run([sys.executable, os.path.abspath(__file__), target, spec_path,
                            out_path], capture_output=True, text=True, env=env, timeout=timeout)
        if p.returncode != 0 or not os.path.exists(out_path):
            raise ChildFailed(f"{target} failed (exit {p.returncode}) on {spec}:\n"
                              f"{p.stdout[-4000:]}\n{p.stderr[-4000:]}")
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
