"""Run the reference SPH codes (PySPH, SPlisHSPlasH) for ``sph bench``.

Each reference code runs in its own subprocess, with the interpreter of the
benchmark venv (``.venv-bench`` at the repo root, made by
``scripts/setup_bench.sh``), so nothing of theirs is imported into our process.

    from launch.external.runner import available, run_external
    if available("pysph"):
        r = run_external("pysph", "wcsph", dx=0.0125, steps=200, threads=2)
        r["particle_steps_per_s"]

The interpreter can be overridden with the environment variable
``SPH_BENCH_PYTHON``.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path
from typing import Sequence

HERE = Path(__file__).resolve().parent
REPO_ROOT = HERE.parent.parent
BENCH_VENV = REPO_ROOT / ".venv-bench"

# LD_PRELOAD that pysplishsplash's wheel needs to import on a headless box.
GL_DISPATCH_CANDIDATES = (
    "/lib/x86_64-linux-gnu/libGLdispatch.so.0",
    "/usr/lib/x86_64-linux-gnu/libGLdispatch.so.0",
)

# code name -> (script, importable module, methods)
CODES = {
    "pysph": ("pysph_dam_break.py", "pysph", ("wcsph",)),
    "splishsplash": ("splishsplash_dam_break.py", "pysplishsplash", ("wcsph", "dfsph")),
}
ALIASES = {"pysplishsplash": "splishsplash", "sphlishsplash": "splishsplash",
           "splish": "splishsplash", "sps": "splishsplash"}


def _canon(code: str) -> str:
    c = code.strip().lower()
    c = ALIASES.get(c, c)
    if c not in CODES:
        raise ValueError(f"unknown reference code {code!r}; known: {sorted(CODES)}")
    return c


def bench_python() -> str:
    """Interpreter that has the reference codes installed."""
    env = os.environ.get("SPH_BENCH_PYTHON")
    if env:
        return env
    p = BENCH_VENV / "bin" / "python"
    if p.exists():
        return str(p)
    return sys.executable


def _env(code: str, threads: int) -> dict:
    env = dict(os.environ)
    t = str(int(threads))
    env["OMP_NUM_THREADS"] = t
    for k in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
        env[k] = t
    env["PYTHONNOUSERSITE"] = "1"
    env.pop("PYTHONPATH", None)
    env.pop("PYTHONHOME", None)
    if code == "splishsplash":
        lib = next((c for c in GL_DISPATCH_CANDIDATES if os.path.exists(c)), None)
        if lib:
            pre = env.get("LD_PRELOAD", "")
            if lib not in pre.split():
                env["LD_PRELOAD"] = (lib + " " + pre).strip()
    return env


def available(code: str) -> bool:
    """True if the reference code is installed for the bench interpreter.

    Checks with ``importlib.util.find_spec`` in a subprocess (the module is
    located, not imported), so it is quick and safe for our process.
    """
    try:
        c = _canon(code)
    except ValueError:
        return False
    module = CODES[c][1]
    py = bench_python()
    if not os.path.exists(py):
        return False
    try:
        r = subprocess.run(
            [py, "-c",
             "import importlib.util, sys; "
             f"sys.exit(0 if importlib.util.find_spec({module!r}) else 1)"],
            capture_output=True, timeout=60, env=_env(c, 1),
        )
    except (OSError, subprocess.SubprocessError):
        return False
    return r.returncode == 0


def _tail(text: str, n: int = 3000) -> str:
    text = text.strip()
    return text if len(text) <= n else "..." + text[-n:]


def run_external(code: str, method: str, dx: float, steps: int, threads: int,
                 timeout_s: float = 900, extra_args: Sequence[str] = ()) -> dict:
    """Run one reference dam break and return its JSON result as a dict.

    Keys: code, method, particles, boundary_particles, neighbours, dt, steps,
    threads, wall_s, particle_steps_per_s (plus code-specific extras).
    Raises RuntimeError (naming the code and the tail of stderr) on failure.
    """
    c = _canon(code)
    script, _module, methods = CODES[c]
    m = method.strip().lower()
    if m not in methods:
        raise ValueError(f"{c} supports methods {methods}, not {method!r}")
    cmd = [bench_python(), str(HERE / script), "--dx", repr(float(dx)),
           "--steps", str(int(steps)), "--threads", str(int(threads))]
    if c == "splishsplash":
        cmd += ["--method", m]
    cmd += list(extra_args)

    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, env=_env(c, threads), cwd=str(REPO_ROOT),
                            start_new_session=True)
    try:
        out, err = proc.communicate(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        out, err = proc.communicate()
        raise RuntimeError(
            f"{c} ({m}) benchmark timed out after {timeout_s:.0f} s; "
            f"stderr tail:\n{_tail(err)}") from None
    if proc.returncode != 0:
        raise RuntimeError(
            f"{c} ({m}) benchmark failed with exit code {proc.returncode}; "
            f"command: {' '.join(cmd)}\nstderr tail:\n{_tail(err)}")
    for line in reversed(out.strip().splitlines()):
        line = line.strip()
        if line.startswith("{"):
            try:
                return json.loads(line)
            except json.JSONDecodeError:
                break
    raise RuntimeError(
        f"{c} ({m}) benchmark printed no JSON result; stdout tail:\n{_tail(out)}"
        f"\nstderr tail:\n{_tail(err)}")


if __name__ == "__main__":  # tiny CLI for manual checks
    import argparse

    ap = argparse.ArgumentParser(description="run one reference dam break")
    ap.add_argument("code")
    ap.add_argument("method", nargs="?", default="wcsph")
    ap.add_argument("--dx", type=float, default=0.0125)
    ap.add_argument("--steps", type=int, default=200)
    ap.add_argument("--threads", type=int, default=1)
    a = ap.parse_args()
    if not available(a.code):
        sys.exit(f"{a.code} is not installed (run scripts/setup_bench.sh)")
    print(json.dumps(run_external(a.code, a.method, a.dx, a.steps, a.threads)))
