"""Progress while numba compiles (launch/compiling.py): one line when a compilation starts, the
elapsed time while it goes on, the total at the end; nothing for a function already compiled, nor
for a warm run (its literal dispatch fires short compile events)."""
import re
import time

import pytest

from launch.compiling import START, report_compiling


def test_a_compilation_is_reported_with_its_elapsed_time():
    from numba import njit
    said = []
    report_compiling(every=0.05, say=said.append, announce_after=0.0)
    namespace = {}
    # a function numba has never seen (no cache), which compiles for a moment
    exec("def f(a):\n    s = 0.0\n" + "".join(f"    s += a[{i}] * {i}.5\n" for i in range(200)) + "    return s",
         namespace)
    f = njit(namespace["f"])
    import numpy as np
    assert f(np.ones(200)) > 0
    deadline = time.monotonic() + 10
    while not any(s.startswith("kernels compiled in") for s in said) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert said[0] == f"{START} ..."
    assert any(s.startswith("compiling kernels: ") and s.endswith(" s so far") for s in said)
    assert said[-1].startswith("kernels compiled in") and "cached for the next runs" in said[-1]
    # once compiled, a call says nothing more
    n = len(said)
    f(np.ones(200))
    time.sleep(4.0)
    assert len(said) == n


def test_a_run_whose_kernels_are_cached_says_nothing_about_compiling(tmp_path):
    import subprocess
    import sys
    from pathlib import Path
    root = Path(__file__).resolve().parent.parent
    run = [sys.executable, "-m", "launch.cli", "run", "configs/tiny.toml", "--steps", "5", "--quiet", "--no-viewer"]
    subprocess.run(run + ["--out", str(tmp_path / "a")], cwd=root, capture_output=True, timeout=600)  # warms
    done = subprocess.run(run + ["--out", str(tmp_path / "b")], cwd=root, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert "compil" not in done.stderr, done.stderr


@pytest.mark.slow  # a cold compile of a scene's kernels (1.5-3 minutes): the slow tier; the default tier's
# multi-process bitwise tests already compare processes that compiled kernels with processes that loaded them
def test_the_process_that_compiles_the_kernels_gets_the_bits_of_every_process_that_loads_them(tmp_path):
    # Given an empty kernel cache and a scene whose neighbour passes reassociate their sums (numba's
    # JIT and its cache's object code once scheduled them differently: 3e-16 apart after 300 steps)
    import os
    import subprocess
    import sys
    from pathlib import Path
    import numpy as np
    root = Path(__file__).resolve().parent.parent
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"))
    env.pop("SPH_FMA", None)
    run = [sys.executable, "-m", "launch.cli", "run", "configs/dam_break_2d.toml", "--set", "particles.spacing=0.02",
           "--set", "sph.density=continuity", "--precision", "f64", "--steps", "300", "--no-viewer"]
    # When one run compiles them (printing their machine code) and a second run loads them from the cache
    cold = subprocess.run(run + ["--out", str(tmp_path / "cold")], cwd=root, env=dict(env, NUMBA_DUMP_ASSEMBLY="1"),
                          capture_output=True, text=True, timeout=900)
    warm = subprocess.run(run + ["--out", str(tmp_path / "warm")], cwd=root, env=env, capture_output=True, text=True,
                          timeout=300)
    # Then both end with the same bits, the first said it compiled, and neither compiled in its own process
    assert cold.returncode == 0 and warm.returncode == 0, cold.stderr + warm.stderr
    assert START in cold.stderr and "sph.compile" not in warm.stderr, cold.stderr + warm.stderr
    assert "compiled in this process" not in cold.stderr + warm.stderr
    a, b = np.load(tmp_path / "cold" / "final.npz"), np.load(tmp_path / "warm" / "final.npz")
    for key in ("id", "x", "v", "rho"):
        assert np.array_equal(a[key], b[key]), key
    # and no kernel holds a fused multiply-add (what the two paths once placed differently: sphcore/__init__.py),
    # although the CPU's features, FMA among them, are left on
    machine_code = cold.stdout + cold.stderr
    assert machine_code.count("ASSEMBLY") > 20, "no machine code was printed"
    fused = re.findall(r"\b(?:vf(?:n?m(?:add|sub)|maddsub|msubadd)\d{3}[ps][sdh]|f(?:n?madd|n?msub|mla|mls))\b",
                       machine_code)
    assert not fused, sorted(set(fused))


PROBE = '''
import numba

from sphcore.backends.literal import literal_dispatch


@literal_dispatch(1)
@numba.njit(cache=True)
def scaled(k, x):
    return x * k
'''

COUNT_COMPILES = '''
import sys, time
sys.path.insert(0, sys.argv[1])
from sphcore.backends import literal
import probe_module
compiled = []
real = literal._compile_elsewhere


def slowly(dispatcher, sig):  # a compile that lasts: every process starts before the first is done
    compiled.append(sig)
    time.sleep(3.0)
    real(dispatcher, sig)


literal._compile_elsewhere = slowly
assert probe_module.scaled(3, 2.0) == 6.0
print(len(compiled))
'''


def test_processes_that_miss_the_same_kernel_at_once_compile_it_once_between_them(tmp_path):
    # Given a literal-dispatched kernel no cache holds, and three processes calling it at once (as the
    # peers of a run started cold do), each compile taking seconds
    import os
    import subprocess
    import sys
    from pathlib import Path
    root = Path(__file__).resolve().parent.parent
    (tmp_path / "probe_module.py").write_text(PROBE)
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"))
    runs = [subprocess.Popen([sys.executable, "-c", COUNT_COMPILES, str(tmp_path)], cwd=root, env=env,
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for _ in range(3)]
    outs = [run.communicate(timeout=300) for run in runs]
    # Then each got its answer, and one of them compiled it; the others waited and loaded it
    assert all(run.returncode == 0 for run in runs), [err[-2000:] for _, err in outs]
    assert sum(int(out.strip().splitlines()[-1]) for out, _ in outs) == 1, outs
    assert not any("compiled in this process" in err for _, err in outs)


def test_a_compile_lock_that_is_never_released_delays_a_process_and_does_not_hang_it(tmp_path, monkeypatch, caplog):
    # Given a specialisation's lock held by another holder (a stopped process) that never lets go
    import fcntl
    import types
    from sphcore.backends import literal
    func = types.SimpleNamespace(__module__="probe", __qualname__="scaled", __name__="scaled")
    dispatcher = types.SimpleNamespace(py_func=func, _cache=types.SimpleNamespace(cache_path=str(tmp_path)))
    with literal._compiling(dispatcher, "(int64,)"):
        held = open(next(tmp_path.glob("compiling-*.lock")), "a+b")
    fcntl.flock(held, fcntl.LOCK_EX)
    monkeypatch.setattr(literal, "LOCK_WAIT_S", 0.5)
    # When this process wants it
    started = time.monotonic()
    with caplog.at_level("WARNING", logger="sph.compile"):
        with literal._compiling(dispatcher, "(int64,)"):
            waited = time.monotonic() - started
    held.close()
    # Then it waited LOCK_WAIT_S, said so, and went on to compile it itself
    assert 0.5 <= waited < 5.0
    assert "scaled: waited 0.5 s for another process to compile it; compiling it here" in caplog.text


def _plant(folder, package, marker):
    """A package named like one of ours in ``folder`` that leaves ``marker`` when imported (as another
    checkout's, or anybody's in a shared folder such as /tmp, would run its code)."""
    (folder / package).mkdir()
    (folder / package / "__init__.py").write_text(f"open({str(marker)!r}, 'w').close()\n")


def test_the_compile_helper_imports_this_code_wherever_it_starts_and_refuses_other_sources(tmp_path):
    # Given a folder holding a planted sphcore package and another copy of grid.py
    import pickle
    import shutil
    import subprocess
    import sys
    from sphcore import grid
    from sphcore.backends import literal
    from sphcore.children import module_command, module_env
    marker = tmp_path / "planted code ran"
    _plant(tmp_path, "sphcore", marker)
    copy = tmp_path / "grid.py"
    shutil.copy(grid.__file__, copy)
    # When the compile helper is started there as it is, and asked to compile from that copy
    helper = subprocess.Popen(module_command("sphcore.backends.literal"), env=module_env(), cwd=tmp_path,
                              stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    literal._send(helper.stdin, pickle.dumps(("sphcore.grid", str(copy), "_filter_neighbours", ())))
    answer = literal._receive(helper.stdout)
    helper.stdin.close()
    assert helper.wait(timeout=120) == 0, helper.stderr.read()[-2000:]
    # Then the planted package never ran, and the helper refused a module that is not the file asked for
    # (it compiles only the asking process's sources into the cache)
    assert not marker.exists()
    assert answer.startswith(b"ImportError") and b"in the asking process" in answer, answer
    # (where ``python -m`` alone, as the helper was started before, runs the planted code)
    subprocess.run([sys.executable, "-m", "sphcore.backends.literal"], cwd=tmp_path, input=b"", capture_output=True,
                   timeout=120)
    assert marker.exists()
