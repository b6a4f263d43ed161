"""float32 stays float32 on the CPU: no float64 arithmetic in the machine code of a float32 pass.

tests/test_cuda.py counts float64 instructions in the PTX of every float32 kernel; the CPU drivers
can go wrong where the PTX does not. numba types a ``prange`` index as uint64, and uint64 with int64
is float64 arithmetic: the neighbour-list builder's ``j != i`` once converted every candidate j to
float64 and compared it there (2026-12-05; the float32 list build took 17.9-18.4 ms against
float64's 14.9-15.0 ms on the 49k dam break, 14.7 ms once fixed: scripts/investigations/
list_build_precision.py, docs/BENCHMARKS.md). Cached machine code cannot be inspected, so the
kernels are compiled here afresh (no cache) from the same Python: the list builder's two drivers
and the default scene's density and force drivers, the passes every step runs.

x86-64 only: the mnemonics counted are that architecture's.
"""
import platform
import re
import types

import numba
import numpy as np
import pytest

from sphcore import grid as grid_mod
from sphcore import stages
from sphcore.backends import cpu
from sphcore.scene import load_scene
from sphcore.solver import Simulation

pytestmark = pytest.mark.skipif(platform.machine() not in ("x86_64", "AMD64"),
                                reason="counts x86-64 mnemonics")

# float64 arithmetic, comparisons and conversions into float64 (moves, shuffles and bit operations
# on 64-bit lanes are not arithmetic: integer code uses them too)
F64 = re.compile(r"^v?(add|sub|mul|div|sqrt|min|max|round|cmp\w*|u?comi|f\w*madd\w*|f\w*msub\w*)[sp]d$"
                 r"|^v?cvt(si2|ss2|ps2|dq2)[sp]d\w*$")


def float64_arithmetic(dispatcher) -> dict:
    """{mnemonic: count} of the float64 arithmetic in every compiled signature of ``dispatcher``."""
    found = {}
    for sig in dispatcher.overloads:
        for line in dispatcher.inspect_asm(sig).splitlines():
            if line.startswith("\t") and not line.startswith("\t."):
                mnemonic = line.split()[0]
                if F64.match(mnemonic):
                    found[mnemonic] = found.get(mnemonic, 0) + 1
    return found


@numba.njit(parallel=True)
def _float64_sum(x, out):
    for i in numba.prange(x.shape[0]):
        out[i] = x[i] * 0.5 + 1.0


def test_the_counter_sees_float64():
    """A loop over float64 values, which the counter must see (it saw the list builder's before the fix)."""
    _float64_sum(np.ones(4), np.zeros(4))
    found = float64_arithmetic(_float64_sum)
    assert sum(found.values()) > 0, found


def _stepped(precision):
    scene = load_scene("configs/dam_break.toml", ["particles.spacing=0.05", "time.mode='fixed'", "time.dt=0.0001"])
    sim = Simulation(scene, precision)
    sim.step()
    return sim


def _fresh_list_builder(sim, rows=None):
    """grid._build_neighbours (or _build_neighbour_rows) compiled afresh for ``sim``'s arrays."""
    g, s = sim.grid, sim.state
    source = grid_mod._build_neighbours if rows is None else grid_mod._build_neighbour_rows
    fresh = numba.njit(parallel=True)(source.dispatcher.py_func)
    args = (g.contiguous, g.cell_begin, g.cell_end, g.origin, g.cell, g.inv_cell, g.ncell, g.reach, g.period, g.H2,
            g.nbr, g.counts)
    fresh(0, s.x, s.n_owned if rows is None else rows, *args)
    return fresh


def test_the_float32_list_builder_computes_in_float32():
    sim = _stepped("f32")
    assert sim.state.x.dtype == np.float32
    for rows in (None, np.arange(sim.state.n_owned, dtype=np.int64)):
        fresh = _fresh_list_builder(sim, rows)
        assert float64_arithmetic(fresh) == {}, ("rows" if rows is not None else "all rows", float64_arithmetic(fresh))


def test_the_float32_density_and_force_passes_compute_in_float32(monkeypatch):
    compiled = {}
    cached_driver = cpu.driver

    def fresh_driver(stage, choices):
        key = (stage.name, choices)
        if stage not in (stages.DENSITY, stages.FORCES):
            return cached_driver(stage, choices)
        if key not in compiled:
            source = cpu.cpu_source(stage, dict(zip(stage.choices, choices))).replace("cache=True", "cache=False")
            source = "\n".join(line for line in source.splitlines() if "literal_dispatch" not in line)
            module = types.ModuleType(f"fresh_{stage.name}")
            exec(compile(source, module.__name__, "exec"), module.__dict__)
            compiled[key] = getattr(module, stage.name)
        return compiled[key]

    monkeypatch.setattr(cpu, "driver", fresh_driver)
    sim = _stepped("f32")
    found = {name: float64_arithmetic(d) for (name, _), d in compiled.items()}
    assert found == {"density": {}, "forces": {}}, found
