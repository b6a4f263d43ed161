"""Child processes that run this package's own modules: the compile helper (backends/literal.py), a
run's peers and viewer (launch/local.py), the benchmark's runs (launch/bench.py, bench_network.py).

``python -m MODULE`` puts the working folder first on the child's import path, so a ``sphcore/``,
``nodes/`` or ``launch/`` folder there is imported instead of this code: another checkout's, or one
anybody could write in a shared folder such as /tmp. Its code then runs under the user's name, and
the compile helper compiles the other sources, not the asking process's (measured 2026-12-06: `sph
validate dam_break --quick` started from the folder of another checkout, with one changed line that
changes no value, gave a late front speed of 1.557 on its first run and 1.522 on every run after,
likely because the helper cached the other checkout's kernels under that checkout's key and the run
compiled its own in-process; with a planted ``sphcore/__init__.py`` the helper ran it).

A child here is started with ``-P`` (no working folder on its path, Python 3.11) and with the folder
that holds this process's ``sphcore`` first on PYTHONPATH: it imports the code this process
imported, wherever it was started and however that code was found (installed, on PYTHONPATH, or the
working folder of a source checkout).

The peers a hosts file starts over ssh (launch/hosts.py) run in the repository folder the user names
(``--remote-dir``), on purpose; the SLURM scripts (launch/slurm) run the installed package with -P.
Neither is started from here.
"""
from __future__ import annotations

import os
import sys
from pathlib import Path

PACKAGE_ROOT = str(Path(__file__).resolve().parents[1])  # the folder that holds sphcore, nodes and launch


def module_command(module: str, *args: str) -> list[str]:
    """The command line that runs ``python -m module args`` as this process's interpreter, without
    the working folder on its import path."""
    return [sys.executable, "-P", "-m", module, *args]


def module_env(env: dict | None = None) -> dict:
    """``env`` (default: this process's environment) with PACKAGE_ROOT first on PYTHONPATH."""
    env = dict(os.environ if env is None else env)
    rest = [p for p in env.get("PYTHONPATH", "").split(os.pathsep) if p and p != PACKAGE_ROOT]
    env["PYTHONPATH"] = os.pathsep.join([PACKAGE_ROOT, *rest])
    return env
