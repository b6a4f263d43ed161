"""Which tests pay for numba's compiling? A pytest plugin that charges each compile to the test that
was running when it happened.

It listens to numba's "numba:compile" events in every pytest process (the xdist workers too) and
appends one JSON line per top-level compile to ``$SPH_COMPILE_LOG/<pid>.jsonl``: the test's node id,
the function, its signature (shortened) and the seconds it took (a driver compiled by the helper
process of sphcore/backends/literal.py counts in full: the event wraps the wait for it). Compiles in
child processes that a test starts (``sph run``, peers) are not seen. Run it on a cold cache:

    SPH_COMPILE_LOG=/tmp/compiles PYTHONPATH=.:scripts/investigations NUMBA_CACHE_DIR=/tmp/cold \\
        .venv/bin/python -m pytest -p compile_per_test -n 2 --dist loadfile -q
    .venv/bin/python scripts/investigations/compile_per_test.py /tmp/compiles     # the table
"""
import collections
import json
import os
import time
from pathlib import Path

_current = {"test": "(collection)"}


def pytest_configure(config):
    folder = os.environ.get("SPH_COMPILE_LOG")
    if not folder:
        return
    from numba.core import event
    Path(folder).mkdir(parents=True, exist_ok=True)
    path = Path(folder) / f"{os.getpid()}.jsonl"
    stack = []

    class Charge(event.Listener):
        def on_start(self, ev):
            stack.append(time.perf_counter())

        def on_end(self, ev):
            seconds = time.perf_counter() - stack.pop()
            if stack:  # nested in another compile: counted in that one
                return
            func = ev.data["dispatcher"].py_func
            with open(path, "a") as f:
                f.write(json.dumps({"test": _current["test"], "function": f"{func.__module__}.{func.__qualname__}",
                                    "args": str(ev.data["args"])[:120], "seconds": round(seconds, 2)}) + "\n")

    event.register("numba:compile", Charge())


def pytest_runtest_setup(item):
    _current["test"] = item.nodeid


def main(folder: str):
    rows = [json.loads(line) for p in Path(folder).glob("*.jsonl") for line in p.read_text().splitlines()]
    per_test = collections.Counter()
    per_function = collections.Counter()
    for r in rows:
        per_test[r["test"]] += r["seconds"]
        per_function[r["function"].rsplit(".", 1)[-1]] += r["seconds"]
    print(f"{len(rows)} compiles, {sum(per_test.values()):.0f} s in all\n\nby test:")
    for test, s in per_test.most_common(40):
        print(f"{s:8.1f} s  {test}")
    print("\nby function:")
    for name, s in per_function.most_common(25):
        print(f"{s:8.1f} s  {name}")


if __name__ == "__main__":
    import argparse
    ap = argparse.ArgumentParser(description="The compile seconds per test and per function that a suite run "
                                 "with this plugin logged (see the module docstring).")
    ap.add_argument("folder", help="the $SPH_COMPILE_LOG folder of the run")
    main(ap.parse_args().folder)
