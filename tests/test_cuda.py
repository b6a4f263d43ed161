"""The CUDA backend: parity with the CPU backend, valid CUDA code, graceful absence.

Without a GPU (CI) the kernels run in numba's CUDA simulator, in a subprocess (NUMBA_ENABLE_CUDASIM
must be set before numba is imported): that checks the kernels' indexing, launches, device binning,
the host mirror and the halo exchanges through it. That every kernel is valid CUDA is checked by
compiling it to PTX (NVVM, no GPU needed). ``pytest -m gpu`` (make test-gpu) runs the same parity
cases on a real GPU.
"""
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parent.parent
PARITY = ROOT / "tests" / "cuda_parity.py"

# Largest allowed difference, scaled by each field's natural size (tests/cuda_parity.py). float64:
# the issue's ~1e-12. float32: positions, density and pressure within 1e-6. Float32 passes sum in
# float32 (physics/real.py), and the CPU's reassociated sums (cpu.FASTMATH) round differently from
# the GPU's sequential ones: the acceleration is a sum of pressure terms that cancel to ~g, so its
# round-off relative to max |a| is a few 1e3 float32 epsilons, and the velocity inherits it (tiny.toml,
# 3 steps, 2026-12-02: a 3.8e-4, v 1.6e-6; with float64 accumulators before: a 7.7e-5 on an H200).
TOL = {"f64": {"x": 1e-12, "v": 1e-12, "rho": 1e-12, "p": 1e-12, "a": 1e-11},
       "f32": {"x": 1e-6, "v": 4e-6, "rho": 1e-6, "p": 1e-6, "a": 1e-3}}


# The cases, each tier in two groups of about equal cost run side by side (the suite's other tests
# wait for the fixture, so the second core would otherwise idle through it). Every simulated thread is
# Python, so the cases are small (tests/cuda_parity.py: the tiny scene at 117 particles, the 2D scenes
# at 90-240), one or two blocks of threads each: with the CPU drivers already compiled, each default
# case takes 5-24 s on one core and the 2D DFSPH across two peers 35-46 s (2026-12-07, with the
# simulator's GIL handed over every 0.3 ms: cuda_parity.py; tiny_f64 took 160 s at the tiny scene's
# own 498 particles on 2026-12-04). The slow tier adds the 3D
# DFSPH cases (one process, two peers, two walking peers), the obstacle and the carried density's own
# case (walk_terms_f64 carries the density already).
GROUPS = (["dfsph_peers_2d_f64", "open_f64", "tiny_f64", "terms_f64", "difference_f64"],
          ["tiny_f32", "periodic_f64", "peers_f64", "walk_terms_f64", "moving_walls_f64", "floating_f64", "rotating_f64",
           "damping_f64"])
SLOW_GROUPS = (["dfsph_f64", "dfsph_peers_f64", "continuity_f64"], ["walk_dfsph_peers_f64", "obstacle_f64"])


def _parity(simulator: bool, groups=GROUPS) -> dict:
    env = dict(os.environ)
    if simulator:
        env["NUMBA_ENABLE_CUDASIM"] = "1"
        env["NUMBA_NUM_THREADS"] = "1"  # one core per group
    results = {}
    with tempfile.TemporaryDirectory() as tmp:  # files, not pipes: neither child can block on a full pipe
        logs = [(Path(tmp) / f"{k}.out", Path(tmp) / f"{k}.err") for k in range(len(groups))]
        runs = []
        for group, (out, err) in zip(groups, logs):
            with open(out, "w") as fo, open(err, "w") as fe:
                runs.append(subprocess.Popen([sys.executable, str(PARITY), *group], cwd=ROOT, env=env,
                                             stdout=fo, stderr=fe))
        for run, (out, err) in zip(runs, logs):
            assert run.wait(timeout=1500) == 0, err.read_text()[-4000:]
            results.update(json.loads(out.read_text().strip().splitlines()[-1]))
    return results


def test_the_groups_hold_every_parity_case():
    sys.path.insert(0, str(ROOT / "tests"))
    import cuda_parity
    assert sorted(sum(GROUPS + SLOW_GROUPS, [])) == sorted(cuda_parity.CASES)


@pytest.fixture(scope="module")
def parity():
    return _parity(simulator=True)


@pytest.fixture(scope="module")
def slow_parity():
    return _parity(simulator=True, groups=SLOW_GROUPS)


def _check(result: dict, precision: str, fields=("x", "v", "rho", "p", "a")):
    assert result["same_particles"]
    for f in fields:
        assert result[f] <= TOL[precision][f], (f, result[f])


def _check_peers(result: dict):
    """Two CUDA peers against one CPU process (tests/cuda_parity.peers_case)."""
    assert result["ghosts"] > 0  # the halo really carried particles
    _check(result, "f64", ("x", "v", "rho"))


def test_stages_match_cpu(parity):
    r = parity["tiny_f64"]
    # binning and neighbour search are exact: same (cell, id) order, same lists in the same order
    assert r["same_order"] and r["same_counts"] and r["same_neighbour_lists"]
    _check(r["stage"], "f64", ("rho", "p", "a"))
    _check(r["steps"], "f64")
    assert r["dt_rel"] < 1e-12 and r["leaks"] == [0, 0]


def test_float32_steps_match_cpu(parity):
    _check(parity["tiny_f32"], "f32")


@pytest.mark.parametrize("case", ["terms_f64", "periodic_f64", "walk_terms_f64", "moving_walls_f64", "floating_f64",
                                  "rotating_f64", "damping_f64", "difference_f64"])
def test_options_match_cpu(parity, case):
    """Optional terms (XSPH, surface tension, vorticity confinement, shifting), leapfrog, Morris
    viscosity, the cubic spline kernel, periodic axes, the cell walk with the carried density, moving
    and turning walls, a floating body (where it moved to: body_x; how it turned: body_R), a damping
    zone, the difference form of the pressure gradient."""
    _check(parity[case], "f64")
    assert parity[case].get("body_x", 0.0) <= TOL["f64"]["x"]
    assert parity[case].get("body_R", 0.0) <= 1e-12
    if case == "floating_f64":  # the body turned (its torque was reduced on the device too)
        assert parity[case]["body_turned"] > 1e-9, parity[case]


@pytest.mark.slow
@pytest.mark.parametrize("case", ["obstacle_f64", "dfsph_f64", "continuity_f64"])
def test_more_options_match_cpu(slow_parity, case):
    """An obstacle with Müller viscosity, the Müller kernel and a linear EOS; the DFSPH solver on one
    process (its iterations, warm start and error reduction on the device); the carried density."""
    _check(slow_parity[case], "f64")


@pytest.mark.slow
@pytest.mark.parametrize("case", ["dfsph_peers_f64", "walk_dfsph_peers_f64"])
def test_3d_dfsph_peers_on_cuda_match_one_cpu_process(slow_parity, case):
    _check_peers(slow_parity[case])


def test_inlets_and_outlets_on_cuda_match_cpu(parity):
    """A layer enters at the inlet and rows leave at the outlet within the compared steps, alike."""
    r = parity["open_f64"]
    before, cpu, gpu = (tuple(c) for c in r["counts"])
    assert cpu == gpu and cpu[1] > before[1] and cpu[2] > before[2], r["counts"]
    _check(r, "f64")


@pytest.mark.parametrize("case", ["peers_f64", "dfsph_peers_2d_f64"])
def test_peers_on_cuda_match_one_cpu_process(parity, case):
    _check_peers(parity[case])


PTX_CHECK = """
import json, sys
from sphcore import stages
from sphcore.backends import cuda
dtype, part, parts = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
ptx = cuda.compile_all(dtype=dtype, stages=stages.STAGES[part::parts], binning=part == 0)
if len(sys.argv) > 4:  # and one kernel by its label in float64: the counter's own check
    name, *choices = sys.argv[4].split()
    combo = {c: int(v) for c, v in (choice.split("=") for choice in choices)}
    stage = next(s for s in stages.STAGES if s.name == name)
    ptx.update({"f64 " + k: v for k, v in cuda.compile_all(dtype="f64", stages=[stage], binning=False,
                                                        combinations=lambda s: [combo]).items()})
print(json.dumps({name: {"ok": ".target sm_90" in text and ".entry" in text,
                         "f64": cuda.float64_instructions(text)} for name, text in ptx.items()}))
"""
# float64 instructions a float32 kernel may hold, each with the reason (tests/ptx_f64_in_f32.json)
F64_ALLOWED = json.loads((ROOT / "tests" / "ptx_f64_in_f32.json").read_text())
FORCES_DEFAULT = "forces kernel=2 viscosity=1 viscosity_switch=0 pressure_gradient=0 periodic=0 neighbours=0"


def _compile_ptx(precision: str, probe_f64: bool = False) -> dict:
    """{kernel label: {"ok", "f64"}} of every kernel in ``precision``, compiled to PTX for sm_90 in two
    processes side by side, half the stages each (NVVM is the slow part and uses one core);
    ``probe_f64`` adds the float64 build of the default force kernel as "f64 <label>"."""
    runs = [subprocess.Popen([sys.executable, "-c", PTX_CHECK, precision, str(part), "2",
                              *([FORCES_DEFAULT] if probe_f64 and part == 1 else [])],
                             cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for part in (0, 1)]
    out = {}
    for run in runs:
        text, err = run.communicate(timeout=1800)
        assert run.returncode == 0, err[-3000:]
        out.update(json.loads(text.strip().splitlines()[-1]))
    return out


@pytest.fixture(scope="module")
def ptx():
    """{"f32": every kernel's PTX check, and the float64 force kernel's}. The float64 build of every
    kernel is the slow tier's (test_every_kernel_compiles_to_ptx_in_float64): the same row functions,
    which float32 compiles already, at twice the suite's time."""
    return {"f32": _compile_ptx("f32", probe_f64=True)}


def _check_compiled(compiled: dict, precision: str):
    from sphcore import stages
    expected = {s.name + "".join(f" {c}={v}" for c, v in combo.items())
                for s in stages.STAGES for combo in stages.covering_choices(s)}
    assert expected <= set(compiled), (precision, expected - set(compiled))
    # the default path of a scene (Wendland C2, Tait, artificial viscosity) is among them
    assert FORCES_DEFAULT in compiled, precision
    assert "density kernel=2 eos=1 periodic=0 neighbours=0 pair_gradients=0 continuity=0" in compiled, precision
    # and every neighbour pass compiles walking the cells as well
    walking = {s.name for s in stages.STAGES if "neighbours" in s.choices}
    assert walking == {k.split()[0] for k in compiled if " neighbours=1" in k and not k.startswith("f64 ")}, precision
    assert all(c["ok"] for c in compiled.values()), (precision, [k for k, c in compiled.items() if not c["ok"]])


def test_every_kernel_compiles_to_ptx(ptx):
    """The shared row functions are valid CUDA: every stage's kernel compiles for an H100 (sm_90) in
    float32, with every value of every choice it takes (stages.covering_choices), and so do the
    binning kernels."""
    _check_compiled(ptx["f32"], "f32")


@pytest.mark.slow
def test_every_kernel_compiles_to_ptx_in_float64():
    _check_compiled(_compile_ptx("f64"), "f64")


def test_float32_kernels_compute_in_float32(ptx):
    """No float64 instruction in a float32 kernel's PTX (Python float literals promote: physics/real.py)
    beyond the few tests/ptx_f64_in_f32.json lists, each with its reason; a kernel may hold fewer."""
    allowed = F64_ALLOWED["kernels"]
    found = {k: c["f64"] for k, c in ptx["f32"].items() if not k.startswith("f64 ")}
    over = {k: (n, allowed.get(k, 0)) for k, n in found.items() if n > allowed.get(k, 0)}
    assert not over, f"float64 instructions in float32 kernels (found, allowed): {over}"
    for k in allowed:
        assert k.split()[0] in F64_ALLOWED["why"], f"{k}: no reason given for its float64 instructions"
    # the counter sees float64 where there is some: the float64 build of the force pass is full of it
    assert ptx["f32"]["f64 " + FORCES_DEFAULT]["f64"] > 100


def test_importing_never_needs_cuda():
    code = ("import sys, sphcore.solver, launch.cli, nodes.peer; "
            "print(any(m.startswith('numba.cuda') for m in sys.modules))")
    done = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "False"


SHARED_RACE = """
import threading, time
import numpy as np
import sphcore.backends.cuda  # installs the locked allocation under the simulator
from numba.cuda.simulator import kernelapi
empty = np.empty
def slow_empty(*args, **kwargs):
    time.sleep(0.002)  # the GIL goes to the other threads between a miss and its insert
    return empty(*args, **kwargs)
np.empty = slow_empty
shared, start, got = kernelapi.FakeCUDAShared(0), threading.Barrier(32), []
def block_thread():
    start.wait()
    got.append(shared.array(128, np.int64))
threads = [threading.Thread(target=block_thread) for _ in range(32)]
for t in threads: t.start()
for t in threads: t.join()
print(len(got), len({id(a) for a in got}))
"""


def test_simulated_threads_of_a_block_share_one_shared_array():
    """numba's simulator could give two threads of a block two shared arrays (a dict miss, a GIL
    handoff, a second insert): backends/cuda.locked_shared_arrays. A slow allocation makes the
    handoff certain; without the lock the simulator gave these 32 threads 13 arrays (2026-12-07)."""
    env = dict(os.environ, NUMBA_ENABLE_CUDASIM="1")
    done = subprocess.run([sys.executable, "-c", SHARED_RACE], cwd=ROOT, env=env, capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.split() == ["32", "1"]


def test_backend_cuda_without_gpu_fails_at_once(tmp_path):
    from sphcore.backends import cuda
    if cuda.probe()[0]:
        pytest.skip("a GPU is present: there is nothing to refuse")
    out = tmp_path / "out"
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_ENABLE_CUDASIM"}
    done = subprocess.run([sys.executable, "-m", "launch.cli", "run", "configs/tiny.toml", "--backend", "cuda",
                           "--out", str(out)], cwd=ROOT, env=env, capture_output=True, text=True, timeout=120)
    assert done.returncode == 2
    assert "--backend cuda" in done.stderr and "--backend cpu" in done.stderr
    assert not out.exists()


def test_device_only_with_cuda(tmp_path):
    done = subprocess.run([sys.executable, "-m", "launch.cli", "run", "configs/tiny.toml", "--device", "1",
                           "--out", str(tmp_path / "o")], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert done.returncode == 2 and "--device 1: only with --backend cuda" in done.stderr


@pytest.mark.gpu
def test_parity_on_a_real_gpu():
    results = _parity(simulator=False, groups=tuple(a + b for a, b in zip(GROUPS, SLOW_GROUPS)))
    assert results["tiny_f64"]["same_neighbour_lists"]
    _check(results["tiny_f64"]["stage"], "f64", ("rho", "p", "a"))
    _check(results["tiny_f64"]["steps"], "f64")
    _check(results["tiny_f32"], "f32")
    for case in ("terms_f64", "periodic_f64", "obstacle_f64", "dfsph_f64", "continuity_f64"):
        _check(results[case], "f64")
    for case in ("peers_f64", "dfsph_peers_f64", "dfsph_peers_2d_f64"):
        _check_peers(results[case])


@pytest.mark.gpu
def test_long_gpu_run_stays_close_to_cpu():
    """200 steps on the GPU stay within 1e-8 m (spacing 1.25e-2 m) of the CPU run: round-off only."""
    from sphcore.scene import load_scene
    from sphcore.solver import Simulation
    sc = load_scene(ROOT / "configs" / "tiny.toml")
    cpu, gpu = Simulation(sc, "f64", "cpu"), Simulation(sc, "f64", "cuda")
    for _ in range(200):
        cpu.step()
        gpu.step()
    a, b = cpu.final_arrays(), gpu.final_arrays()
    assert np.array_equal(a["id"], b["id"])
    assert np.max(np.abs(a["x"] - b["x"])) < 1e-8
