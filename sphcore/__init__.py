"""sphcore: the physics of the SPH simulator (state, kernels, neighbour grid, solvers, boundaries).

No networking here. Importing this package compiles nothing; numba compiles each stage on first use
and caches it on disk.

numba's cache checks only the source file of the function it compiled, not the files of the
functions inlined into it: a driver in backends/cpu.py would keep calling a stale copy of a
changed physics/walls.py function. So the cache lives in a folder named after a hash of the
kernel sources (``~/.cache/sphfluid/numba/<hash>``, or under ``$SPH_CACHE_DIR``): every sphcore
file that imports numba and every sphcore module those import, transitively (their constants are
frozen into the compiled code). Any change to the physics starts a fresh cache; an edit to a file
no kernel can see (scene.py, checkpoint.py, halo.py...) keeps it. Set NUMBA_CACHE_DIR to choose
the folder yourself.

The generated code uses no fused multiply-add. numba emits the code it runs right after compiling
through its JIT, and the code it caches through a separate object-code path; allowed to contract
a * b + c into FMA, the two do it in different places, so the process that compiled a kernel got
different last bits than every later process that loaded it from the cache (measured:
accelerations differed by 1 ulp). The neighbour passes' floating-point licences therefore leave out
'contract' (backends/generate.FASTMATH), and without it LLVM forms no FMA: both paths give the same
bits, and a run is bitwise reproducible whichever process compiled its kernels — which the
distributed runs (peers are separate processes) rely on. The CPU's features are left as they are:
until 2026-12-07 FMA was kept out by taking ``fma`` off them, which on a CPU with AVX-512 also took
AVX-512 off (LLVM makes AVX-512F depend on FMA), so every kernel was compiled for AVX2
(docs/BENCHMARKS.md). SPH_FMA=1 grants 'contract' (faster, but runs are then reproducible only
among processes that loaded their kernels from the same cache); NUMBA_CPU_FEATURES sets the features.
"""
import hashlib
import os
import re
from pathlib import Path

__version__ = "0.1.0"


_IMPORT = re.compile(rb"^[ \t]*(?:from[ \t]+([\w.]+)[ \t]+import[ \t]+(\([^)]*\)|[\w \t,]+)|import[ \t]+([\w.]+))", re.M)


def kernel_sources() -> list[Path]:
    """The sphcore files compiled code can depend on: those importing numba, and every sphcore
    module they import (transitively), sorted."""
    root = Path(__file__).resolve().parent
    imports, module_path = {}, {}
    for path in sorted(root.rglob("*.py")):
        names = set()
        for module, members, plain in _IMPORT.findall(path.read_bytes()):
            if plain:
                names.add(plain.decode())
            else:
                names.add(module.decode())  # and "from pkg import module"
                names.update(f"{module.decode()}.{m.strip().decode()}" for m in members.strip(b"()").split(b",") if m.strip())
        imports[path] = names
        parts = ("sphcore",) + path.relative_to(root).with_suffix("").parts
        module_path[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    todo = [p for p, names in imports.items() if any(n == "numba" or n.startswith("numba.") for n in names)]
    seen = set()
    while todo:
        path = todo.pop()
        if path not in seen:
            seen.add(path)
            todo.extend(module_path[n] for n in imports[path] if n in module_path)
    return sorted(seen)


def _source_hash() -> str:
    h = hashlib.sha256()
    root = Path(__file__).resolve().parent
    for path in kernel_sources():
        h.update(str(path.relative_to(root)).encode())
        h.update(path.read_bytes())
    return h.hexdigest()[:16]


def _use_versioned_numba_cache():
    if os.environ.get("NUMBA_CACHE_DIR"):
        return
    import numba
    base = Path(os.environ.get("SPH_CACHE_DIR", Path.home() / ".cache" / "sphfluid"))
    numba.config.CACHE_DIR = str(base / "numba" / _source_hash())


_use_versioned_numba_cache()

from sphcore import faster_compile  # noqa: E402  (after the cache folder is chosen)

faster_compile.patch_cpu()
