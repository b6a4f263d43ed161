"""CUDA backend (numba-cuda): the stages of a step as thin kernels over the shared row functions.

Every kernel runs one thread per row and calls the same ``*_row`` function as the CPU driver
(``physics/*.py``, ``grid.neighbour_row``...), so the physics exists once. The stage kernels are
generated from their declarations (``sphcore/stages.py``, ``backends/generate.cuda_source``): a
factory per stage builds the kernel for one combination of compile-time choices (kernel family,
EOS, viscosity model...), kept for the process; the choice integers are closure constants, so NVVM
prunes unused branches as numba does for the CPU literals.

Binning on the device is the CPU algorithm, step for step: cell keys; histogram (atomic counts);
inclusive prefix scan; scatter (atomic slots: arbitrary order within a bin); insertion sort of each
bin by particle id. The result — rows ordered by (cell, id), neighbour lists scanned in the same cell
order — is therefore the same as on the CPU, whatever order the atomics ran in. Force passes
gather over the neighbour list and write only their own row: no atomics there. Reductions (the
step statistics, the longest neighbour list) reduce per block in shared memory, then combine the
block results with one atomic max per block (max and integer sums do not depend on order).

Neighbour lists are stored column-major (``nbr[i, k]`` at ``i + k * n``): consecutive threads read
consecutive words. The row functions index ``nbr[i, k]`` on both backends; numba compiles the layout.

Under ``NUMBA_ENABLE_CUDASIM=1`` (tests without a GPU) the kernels run in numba's simulator and the
shared row functions run as their CPU-compiled selves (the simulator hands kernels array stand-ins,
which ``_device`` unwraps). That checks the kernels' indexing, launches, binning and data movement;
``compile_all`` checks that every kernel compiles for a real GPU (PTX, no GPU needed).
"""
from __future__ import annotations

import functools
import re
import sys
import threading

import numba
import numpy as np
from numba import cuda
from numba.np import numpy_support

from sphcore import decomposition
from sphcore import faster_compile
from sphcore import grid as grid_mod
from sphcore import state as state_fields
from sphcore.backends import BackendUnavailable
from sphcore.backends.engine import Engine
from sphcore.backends.generate import cuda_source
from sphcore.stages import ARGUMENTS, CHOICES, MAX_REDUCED, STAGES, covering_choices, reduction_slots

SIMULATOR = bool(numba.config.ENABLE_CUDASIM)
faster_compile.patch_cuda()  # numba-cuda's inliner copies in linear time (sphcore/faster_compile.py)
BLOCK = 128          # threads per block for row kernels
SCAN_CHUNK = 64      # elements scanned sequentially by one thread in the prefix scan


class CudaUnavailable(BackendUnavailable):
    """--backend cuda without a usable GPU."""


def probe() -> tuple[bool, str]:
    """(True, device description) when kernels can run here (a GPU, or the simulator), else
    (False, why not). Never raises: numba-cuda reports a missing driver in several ways."""
    if SIMULATOR:
        return True, "numba CUDA simulator (NUMBA_ENABLE_CUDASIM=1)"
    try:
        if not cuda.is_available():
            return False, "no CUDA driver or GPU found (numba.cuda.is_available() is False)"
        dev = cuda.get_current_device()
        name = dev.name.decode() if isinstance(dev.name, bytes) else str(dev.name)
        return True, f"{name} (compute capability {dev.compute_capability[0]}.{dev.compute_capability[1]})"
    except Exception as exc:  # noqa: BLE001 - numba-cuda raises various non-ImportErrors here
        return False, f"CUDA is not usable: {exc}"


def require(device: int | None = None) -> str:
    """Select GPU ``device`` (default: the current one, GPU 0) and describe it; raise CudaUnavailable
    with the reason when there is none."""
    ok, why = probe()
    if not ok:
        raise CudaUnavailable(f"--backend cuda: {why}. Run with --backend cpu, or set NUMBA_ENABLE_CUDASIM=1 "
                              "to use numba's (slow) CUDA simulator")
    if device is not None and not SIMULATOR:
        count = len(cuda.gpus)
        cuda.select_device(device % count)
        ok, why = probe()
    return why


def _unwrap(a):
    """The numpy array behind the simulator's in-kernel array stand-in (anything else unchanged)."""
    item = getattr(a, "__dict__", {}).get("_item")
    if item is not None and hasattr(item, "_ary"):
        return item._ary
    return a


def locked_shared_arrays(shared_class):
    """Make the simulator's ``cuda.shared.array`` give every thread of a block the same array.

    numba's simulator runs a block's threads as Python threads; each one's ``cuda.shared.array``
    looks its call site up in a dict and, on a miss, inserts a fresh ``np.empty``. Two threads that
    both miss (a GIL handoff between the lookup and the insert) get two arrays, and a block
    reduction then reads the uninitialised half it did not write: CI saw a step statistic of 1.4e14
    and a NaN stop (2026-12-07, tests/cuda_parity.py dfsph_peers_2d_f64, at the 0.3 ms switch
    interval that the parity cases run at); an instrumented run here saw one duplicate in 343
    allocations. The lookup and the insert here hold one lock; the call site is the caller's frame
    (file, line), as the simulator keys it, without formatting the whole stack."""
    unlocked = shared_class.array
    lock = threading.Lock()

    def array(self, shape, dtype, alignment=None):
        if alignment is not None or shape == 0:  # errors, and the dynamic shared memory: one buffer
            return unlocked(self, shape, dtype, alignment)
        if isinstance(dtype, numba.types.Type):
            dtype = numpy_support.as_dtype(dtype)
        frame = sys._getframe(1)
        site = (frame.f_code.co_filename, frame.f_lineno)
        with lock:
            found = self._allocations.get(site)
            if found is None:
                found = self._allocations[site] = np.empty(shape, dtype)
        return found
    shared_class.array = array


if SIMULATOR:
    from numba.cuda.simulator import kernelapi
    locked_shared_arrays(kernelapi.FakeCUDAShared)


def _device(fn):
    """How a kernel calls a shared ``@njit`` function: the function itself on a GPU (numba-cuda
    compiles it as a device function); under the simulator, a wrapper running its Python source on
    the unwrapped arrays (the functions it calls still run compiled). Not the row's CPU compilation:
    called from Python its choices are int64 values, not constants, so numba typed and lowered every
    branch of every choice, a minute or more per row function on a cold cache, while the Python row
    steps the simulator's one or two blocks as fast (tests/cuda_parity.py tiny_f64 from an empty
    cache: 95 s against 145 s, the same differences from the CPU; 2026-12-04)."""
    if not SIMULATOR:
        return fn

    def call(*args):
        return fn.py_func(*[_unwrap(a) for a in args])
    return call


def blocks(n: int, block: int = BLOCK) -> int:
    return max((n + block - 1) // block, 1)


def zero(a):
    """a[:] = 0 on the device: a driver memset, 4.8 us for 64 bytes against 97 us for an upload of zeros
    from the host (an H200's host, scripts/investigations/launch_overhead.py, 2026-12-04; the simulator
    has no memset)."""
    if SIMULATOR:
        a.copy_to_device(np.zeros(a.shape, dtype=a.dtype))
    else:
        from numba.cuda.cudadrv.driver import device_memset
        device_memset(a, 0, a.nbytes)


class Traffic:
    """Bytes copied between host and device (summary.json ``device_transfer``): every explicit copy of
    the backend goes through ``up`` and ``down``."""

    def __init__(self):
        self.to_device = 0
        self.to_host = 0

    def up(self, host: np.ndarray, dev=None):
        """``host`` to the device: into ``dev`` (same shape), or a new device array (returned)."""
        self.to_device += host.nbytes
        if dev is None:
            return cuda.to_device(host)
        dev.copy_to_device(host)
        return dev

    def down(self, dev) -> np.ndarray:
        """A host copy of device array ``dev``."""
        host = dev.copy_to_host()
        self.to_host += host.nbytes
        return host

    def summary(self) -> dict:
        return {"to_device_bytes": int(self.to_device), "to_host_bytes": int(self.to_host)}


# -- physics kernels: generated from the stage declarations (one per stage and choice combination) --

def _generated_factories() -> dict:
    """{stage name: make(*choices) -> kernel} from generate.cuda_source (executed here, in memory)."""
    namespace = {"cuda": cuda, "numba": numba, "BLOCK": BLOCK, "_device": _device}
    namespace.update({s.row.py_func.__name__: s.row for s in STAGES})
    exec(compile(cuda_source(STAGES), "<sphcore generated CUDA kernels>", "exec"), namespace)  # noqa: S102
    return {s.name: functools.cache(namespace[f"make_{s.name}"]) for s in STAGES}


KERNELS = _generated_factories()


# -- binning kernels -------------------------------------------------------------------------------

@functools.cache
def _binning_kernels():
    cell_index = _device(grid_mod.cell_index)
    sort_bin_row = _device(grid_mod.sort_bin_row)
    cell_range_row = _device(grid_mod.cell_range_row)

    @cuda.jit
    def cell_keys(x, n, n_owned, origin, inv_cell, ncell, keys, bin_count, flags):
        """keys[i] = cell key of row i (+ ncells for ghost rows); bin_count[key + 1] += 1; flags (the
        binning's two counters, DeviceGrid.flags) zeroed by thread 0 (kernels of a stream run in order,
        so the counters are zero before cell_ranges and the list build add to them)."""
        i = cuda.grid(1)
        if i == 0:
            flags[0] = 0
            flags[1] = 0
        if i < n:
            nx, ny, nz = ncell[0], ncell[1], ncell[2]
            ix = cell_index(x, i, 0, origin, inv_cell, ncell)
            iy = cell_index(x, i, 1, origin, inv_cell, ncell)
            iz = cell_index(x, i, 2, origin, inv_cell, ncell)
            key = (iz * ny + iy) * nx + ix
            if i >= n_owned:
                key += nx * ny * nz
            keys[i] = key
            cuda.atomic.add(bin_count, key + 1, 1)

    @cuda.jit
    def scatter(keys, n, fill, perm):
        """perm[slot] = i with slot taken atomically from its bin (order fixed by the bin sort)."""
        i = cuda.grid(1)
        if i < n:
            slot = cuda.atomic.add(fill, keys[i], 1)
            perm[slot] = i

    @cuda.jit
    def sort_bins(nbins, bin_start, perm, ids):
        c = cuda.grid(1)
        if c < nbins:
            sort_bin_row(c, bin_start, perm, ids)

    @cuda.jit
    def cell_ranges(ncells, bin_start, cell_begin, cell_end, flags):
        c = cuda.grid(1)
        if c < ncells:
            if cell_range_row(c, bin_start, ncells, cell_begin, cell_end):
                cuda.atomic.add(flags, 0, 1)  # only when a migration was missed

    return cell_keys, scatter, sort_bins, cell_ranges


@cuda.jit
def _scan_chunks(a, n, chunk, sums):
    """In-place inclusive scan of a[t*chunk : (t+1)*chunk] by thread t; sums[t] = its total."""
    t = cuda.grid(1)
    lo = t * chunk
    if lo < n:
        hi = min(lo + chunk, n)
        acc = a[lo] * 0
        for k in range(lo, hi):
            acc += a[k]
            a[k] = acc
        sums[t] = acc


@cuda.jit
def _add_offsets(a, n, chunk, scanned_sums):
    """a[k] += total of all chunks before k's chunk."""
    k = cuda.grid(1)
    if k < n:
        t = k // chunk
        if t > 0:
            a[k] += scanned_sums[t - 1]


def scan_buffers(n: int, dtype) -> list:
    """The chunk totals' arrays of every level of ``inclusive_scan`` over n elements, allocated once
    (an allocation per step and level cost a device synchronisation each)."""
    levels = []
    while True:
        n = (n + SCAN_CHUNK - 1) // SCAN_CHUNK
        levels.append(cuda.device_array(n, dtype=dtype))
        if n <= 1:
            return levels


def inclusive_scan(a, n: int, levels=None):
    """In-place inclusive prefix sum of device array a[:n] (chunked, recursive over chunk totals;
    deterministic: integer sums). ``levels``: scan_buffers(n) (allocated here if not given)."""
    levels = scan_buffers(n, a.dtype) if levels is None else levels
    sums = levels[0]
    nchunks = (n + SCAN_CHUNK - 1) // SCAN_CHUNK
    _scan_chunks[blocks(nchunks), BLOCK](a, n, SCAN_CHUNK, sums)
    if nchunks > 1:
        inclusive_scan(sums, nchunks, levels[1:])
        _add_offsets[blocks(n), BLOCK](a, n, SCAN_CHUNK, sums)


@cuda.jit
def _fill(a, n, value):
    """a[:n] = value (any dtype: compiled per argument types)."""
    i = cuda.grid(1)
    if i < n:
        a[i] = value


@cuda.jit
def _copy_1d(src, n, dst):
    i = cuda.grid(1)
    if i < n:
        dst[i] = src[i]


def _row_copy_kernel(ndims: tuple, scatter: bool):
    """dst_f[k] = src_f[rows[k]] (gather) or dst_f[rows[k]] = src_f[k] (scatter) for k < n and each
    field f (``ndims``: each field's number of dimensions, 1 or 2), called as
    kernel(rows, n, src_0, dst_0, src_1, dst_1, ...)."""
    to, fro = ("i", "k") if scatter else ("k", "i")
    body = []
    for f, nd in enumerate(ndims):
        body.append(f"        d{f}[{to}] = s{f}[{fro}]" if nd == 1 else
                    f"        for c in range(s{f}.shape[1]):\n            d{f}[{to}, c] = s{f}[{fro}, c]")
    args = ", ".join(f"s{f}, d{f}" for f in range(len(ndims)))
    source = (f"def copy_rows(rows, n, {args}):\n    k = cuda.grid(1)\n    if k < n:\n        i = rows[k]\n"
              + "\n".join(body) + "\n")
    namespace = {"cuda": cuda}
    exec(compile(source, "<sphcore generated row copy>", "exec"), namespace)  # noqa: S102
    return cuda.jit(namespace["copy_rows"])


@functools.cache
def gather_kernel(ndims: tuple):
    """One kernel gathering several fields' rows, dst_f[k] = src_f[rows[k]] (``ndims``: each field's
    number of dimensions), called as kernel(rows, n, src_0, dst_0, src_1, ...): the grid's reorder is
    one launch, not one per field (the grid stage is launch-bound below millions of particles), and a
    halo message's rows are packed on the device."""
    return _row_copy_kernel(ndims, scatter=False)


def gather_rows(rows, m: int, sources, targets):
    """targets[f][k] = sources[f][rows[k]] for k < m and every field f, in one launch."""
    if m:
        pairs = [a for pair in zip(sources, targets) for a in pair]
        gather_kernel(tuple(a.ndim for a in sources))[blocks(m), BLOCK](rows, m, *pairs)


@functools.cache
def scatter_kernel(ndims: tuple):
    """dst_f[rows[k]] = src_f[k] for each field: received halo rows unpacked on the device (rows are
    distinct: no two threads write one row)."""
    return _row_copy_kernel(ndims, scatter=True)


@cuda.jit
def _inverse_permutation(perm, n, where):
    """where[perm[k]] = k: the row now of each row before the sort (a permutation: no collisions)."""
    k = cuda.grid(1)
    if k < n:
        where[perm[k]] = k


@cuda.jit
def _compose(where, rows, n, out):
    """out[k] = where[rows[k]]."""
    k = cuda.grid(1)
    if k < n:
        out[k] = where[rows[k]]


@cuda.jit
def _set_at(a, rows, n, value):
    """a[rows[k]] = value."""
    k = cuda.grid(1)
    if k < n:
        a[rows[k]] = value


@cuda.jit
def _selected_rows(scanned, n, rows):
    """rows[j] = i for the rows whose flag was 1, in order (``scanned``: the flags' inclusive scan)."""
    i = cuda.grid(1)
    if i < n:
        before = scanned[i - 1] if i > 0 else 0
        if scanned[i] > before:
            rows[before] = i


@cuda.jit
def _count_from(first, n, out):
    """out[k] = first + k for k < n."""
    k = cuda.grid(1)
    if k < n:
        out[k] = first + k


@cuda.jit
def _complement(flags, n, out):
    """out[i] = 1 - flags[i] (flags of 0 and 1)."""
    i = cuda.grid(1)
    if i < n:
        out[i] = 1 - flags[i]


@functools.cache
def _zone_kernel():
    cell_index = _device(grid_mod.cell_index)
    zone_code = _device(decomposition.zone_code)

    @cuda.jit
    def zone(x, n, origin, inv_cell, ncell, rank, cuts, dims, boxes, periodic, reach, owner, mask, flag):
        """decomposition.zone_code of owned row i; flag[i] = 1 where it leaves or is a neighbour's ghost."""
        i = cuda.grid(1)
        if i < n:
            o, b = zone_code(cell_index(x, i, 0, origin, inv_cell, ncell), cell_index(x, i, 1, origin, inv_cell, ncell),
                             cell_index(x, i, 2, origin, inv_cell, ncell), cuts, dims, boxes, ncell, periodic,
                             reach)
            owner[i] = o
            mask[i] = b
            flag[i] = 1 if (o != rank or b != 0) else 0
    return zone


@cuda.jit
def _max_int(values, n, out, slot):
    """out[slot] = max(out[slot], max(values[:n])): block reduction in shared memory, one atomic per
    block."""
    s_max = cuda.shared.array(BLOCK, numba.int32)
    t = cuda.threadIdx.x
    i = cuda.grid(1)
    s_max[t] = values[i] if i < n else 0
    cuda.syncthreads()
    s = BLOCK // 2
    while s > 0:
        if t < s:
            s_max[t] = max(s_max[t], s_max[t + s])
        cuda.syncthreads()
        s //= 2
    if t == 0:
        cuda.atomic.max(out, slot, s_max[0])


@functools.cache
def _neighbour_kernel(periodic):
    row = _device(grid_mod.neighbour_row)

    @cuda.jit
    def neighbours(n_query, x, contiguous, cell_begin, cell_end, origin, cell, inv_cell, ncell, reach, period, H2,
                   nbr, counts):
        i = cuda.grid(1)
        if i < n_query:
            row(periodic, False, i, x, contiguous, cell_begin, cell_end, origin, cell, inv_cell, ncell, reach, period,
                H2, nbr, counts)
    return neighbours


class DeviceGrid:
    """The host grid's geometry plus the per-step sort and neighbour lists on the device.

    Mirrors ``grid.Grid``: after ``bin``, rows are ordered by (cell, id) (owned first, ghosts after);
    ``nbr`` (n, capacity) int32, column-major, and ``counts`` (n,) int32 are the neighbour lists.
    ``counts`` and ``last_permutation`` read on the host are downloaded on demand (outputs, halo).
    """

    def __init__(self, host: grid_mod.Grid, traffic: Traffic, capacity: int = 64):
        self.host = host
        self.traffic = traffic
        self.dtype = host.dtype
        self.ncells = host.ncells
        self.reach = host.reach
        self.periodic = host.periodic
        self.skin = 0.0  # no reused lists on the device (scene.list_skin): a build every step
        self.builds = self.reuses = 0
        self.capacity = capacity
        self.d_origin = cuda.to_device(host.origin)
        self.d_cell = cuda.to_device(host.cell)
        self.d_inv_cell = cuda.to_device(host.inv_cell)
        self.d_ncell = cuda.to_device(host.ncell)
        self.d_period = cuda.to_device(host.period)
        self.bin_start = cuda.device_array(2 * self.ncells + 1, dtype=np.int64)
        self.cell_begin = cuda.device_array(self.ncells, dtype=np.int64)
        self.cell_end = cuda.device_array(self.ncells, dtype=np.int64)
        self._fill = cuda.device_array(2 * self.ncells, dtype=np.int64)
        self._scan_levels = scan_buffers(self.bin_start.shape[0], np.int64)
        # the binning's counters, read back once per step: [cells holding owned and ghost rows (a
        # missed migration), the longest neighbour list]
        self.flags = cuda.device_array(2, dtype=np.int32)
        self.d_nbr = cuda.device_array((0, capacity + 1), dtype=np.int32, order="F")  # + the builder's spare
        self.d_counts = cuda.device_array(0, dtype=np.int32)
        self.d_perm = cuda.device_array(0, dtype=np.int64)
        self._keys = cuda.device_array(0, dtype=np.int64)
        self.n = 0
        self.n_query = 0
        self.contiguous = True
        self._where = cuda.device_array(1, dtype=np.int64)  # the last sort's inverse permutation
        self._where_valid = False

    # host-side views used by outputs and the halo
    @property
    def counts(self):
        return self.traffic.down(self.d_counts[: self.n_query])

    @property
    def last_permutation(self):
        return self.traffic.down(self.d_perm[: self.n])

    def cells_of(self, x):
        return self.host.cells_of(x)

    def __getattr__(self, name):
        """Geometry (origin, cell, ncell, period...) from the host grid."""
        if name == "host":
            raise AttributeError(name)
        return getattr(self.host, name)

    def sort(self, d, check: bool = True):
        """Order the device state ``d`` (DeviceState) by (cell, id): owned rows, then ghost rows.
        ``check``: read the missed-migration counter back now (else the list build reads it with
        its own counter, one synchronisation per step either way)."""
        n = d.n
        if self._keys.shape[0] < n:
            self._keys = cuda.device_array(n, dtype=np.int64)
            self.d_perm = cuda.device_array(n, dtype=np.int64)
        self.n = n
        cell_keys, scatter, sort_bins, cell_ranges = _binning_kernels()
        nb = self.bin_start.shape[0]
        zero(self.bin_start)
        if n:
            cell_keys[blocks(n), BLOCK](d.x, n, d.n_owned, self.d_origin, self.d_inv_cell, self.d_ncell,
                                        self._keys, self.bin_start, self.flags)
        else:
            zero(self.flags)
        inclusive_scan(self.bin_start, nb, self._scan_levels)
        _copy_1d[blocks(nb - 1), BLOCK](self.bin_start, nb - 1, self._fill)
        if n:
            scatter[blocks(n), BLOCK](self._keys, n, self._fill, self.d_perm)
        sort_bins[blocks(nb - 1), BLOCK](nb - 1, self.bin_start, self.d_perm, d.id)
        cell_ranges[blocks(self.ncells), BLOCK](self.ncells, self.bin_start, self.cell_begin, self.cell_end,
                                                self.flags)
        self.contiguous = d.n_owned == n
        self._where_valid = False
        d.reorder(self.d_perm)
        if check:
            self._read_flags()

    def sorted_rows(self, rows) -> object:
        """Device array of the rows now (after this step's sort) of ``rows`` (host indices numbered
        before the sort): the inverse permutation is formed on the device once per sort."""
        if not self._where_valid:
            if self._where.shape[0] < self.n:
                self._where = cuda.device_array(max(self.n, 1), dtype=np.int64)
            if self.n:
                _inverse_permutation[blocks(self.n), BLOCK](self.d_perm, self.n, self._where)
            self._where_valid = True
        rows = np.ascontiguousarray(rows, dtype=np.int64)
        out = cuda.device_array(len(rows), dtype=np.int64)
        if len(rows):
            _compose[blocks(len(rows)), BLOCK](self._where, self.traffic.up(rows), len(rows), out)
        return out

    def _read_flags(self) -> int:
        """The binning's counters from the device (a synchronisation): raise on a missed migration,
        else return the longest neighbour list (0 when none was built)."""
        mixed, most = (int(v) for v in self.traffic.down(self.flags))
        if mixed:
            raise RuntimeError(f"{mixed} grid cells hold both owned and ghost particles: a migration was missed")
        return most

    def build_neighbours(self, x, n_query):
        """Neighbour lists of rows 0..n_query-1; grows the capacity and rebuilds when a list is longer.
        Returns the longest list."""
        self.n_query = n_query
        if self.d_nbr.shape[0] < n_query:
            self.d_nbr = cuda.device_array((n_query, self.capacity + 1), dtype=np.int32, order="F")
            self.d_counts = cuda.device_array(n_query, dtype=np.int32)
        if n_query == 0:
            return self._read_flags()
        kernel = _neighbour_kernel(int(self.periodic))
        while True:
            kernel[blocks(n_query), BLOCK](n_query, x, self.contiguous, self.cell_begin, self.cell_end,
                                           self.d_origin, self.d_cell, self.d_inv_cell, self.d_ncell, self.host.reach,
                                           self.d_period, self.host.H2, self.d_nbr, self.d_counts)
            _max_int[blocks(n_query), BLOCK](self.d_counts, n_query, self.flags, 1)
            most = self._read_flags()
            if most <= self.capacity:
                return most
            self.capacity = int(most * 1.25) + 8
            self.d_nbr = cuda.device_array((max(n_query, self.d_nbr.shape[0]), self.capacity + 1), dtype=np.int32,
                                           order="F")
            zero(self.flags)

    def bin(self, d):
        self.sort(d, check=False)
        return self.build_neighbours(d.x, d.n_owned)


FIELDS = state_fields.FIELDS    # every named per-particle field (state.py)
SORTED = state_fields.CARRIED   # reordered by the grid (with the extras); the rest is recomputed every step


class DeviceState:
    """The particle arrays on the device (the same fields, shapes and units as ParticleState), the
    per-step scratch of the solver, and the wall description."""

    def __init__(self, dtype, traffic: Traffic):
        self.dtype = np.dtype(dtype)
        self.traffic = traffic
        self.n = 0
        self.n_owned = 0
        self.arrays = {}
        self.extra_names = ()  # the state's extra arrays (carried with the particles)
        self._spare = {}

    def upload(self, state, names=FIELDS):
        """Copy host ParticleState arrays to the device (all rows); a full upload takes the state's
        extra arrays (DFSPH's kappa) too."""
        self.n = state.n
        self.n_owned = state.n_owned
        if names is FIELDS:
            self.extra_names = tuple(state.extra)
        for name in names + (self.extra_names if names is FIELDS else ()):
            host = np.ascontiguousarray(state.extra[name] if name in state.extra else getattr(state, name))
            dev = self.arrays.get(name)
            if dev is None or dev.shape != host.shape:
                self.arrays[name] = self.traffic.up(host)
            else:
                self.traffic.up(host, dev)

    def download(self, state, names=FIELDS):
        """Copy device arrays into the host ParticleState (resized to the device's row count)."""
        for name in names:
            setattr(state, name, self.traffic.down(self.arrays[name][: self.n]))
        if names is FIELDS:
            for name in self.extra_names:
                state.extra[name] = self.traffic.down(self.arrays[name][: self.n])
        state.n_owned = self.n_owned

    def reorder(self, perm):
        """Rows of the sorted fields (and extra arrays) gathered by ``perm`` (row k <- row perm[k]) in one
        launch; double-buffered."""
        sources, targets = [], []
        for name in SORTED + self.extra_names:
            src = self.arrays[name]
            dst = self._spare.get(name)
            if dst is None or dst.shape != src.shape or dst.dtype != src.dtype:
                dst = cuda.device_array(src.shape, dtype=src.dtype)
            sources.append(src)
            targets.append(dst)
            self.arrays[name] = dst
            self._spare[name] = src
        gather_rows(perm, self.n, sources, targets)

    def __getattr__(self, name):
        arrays = self.__dict__.get("arrays", {})
        if name in arrays:
            return arrays[name]
        raise AttributeError(name)


class CudaStages(Engine):
    """The stages of ``Simulation.stages`` on the device. The particle arrays live here for the
    whole run; the simulation's host ``state`` is a mirror, downloaded only when something on the
    host reads it (outputs, frames, a peer's halo) and uploaded again when the host replaced it."""

    def __init__(self, sim):
        self.dtype = sim.dtype
        self.traffic = Traffic()
        self.d = DeviceState(sim.dtype, self.traffic)
        self.grid = DeviceGrid(sim.host_grid, self.traffic)
        w = sim.walls
        self.walls = {"wall_kind": cuda.to_device(np.ascontiguousarray(w.kind)),
                      "wall_data": cuda.to_device(np.ascontiguousarray(w.data)),
                      "wall_tables": cuda.to_device(np.ascontiguousarray(w.tables)),
                      "wall_motion": cuda.to_device(np.ascontiguousarray(w.motion)),
                      "wall_zones": cuda.to_device(np.ascontiguousarray(w.zones)),
                      "wall_damping": cuda.to_device(np.ascontiguousarray(w.damping)),
                      "wall_near": cuda.to_device(np.ascontiguousarray(w.near)),
                      "lo": cuda.to_device(sim.model.lo)}
        # a stage's reduced values (stages.REDUCTIONS): the integer kinds, and the real maxima
        self.out = {"int64": cuda.device_array(MAX_REDUCED, dtype=np.int64),
                    "float64": cuda.device_array(MAX_REDUCED, dtype=np.float64)}
        self.device_stale = True   # the host state was replaced: upload before the next stage
        self.host_stale = False    # the device ran a stage since the last download
        self.all_rows = cuda.device_array(0, dtype=np.int64)
        self._split = None
        self._no_pairs = None  # the grad_w placeholder (array)
        super().__init__(sim)

    def allocate(self, shape, initial):
        """A scratch array filled with ``initial`` on the device (nothing crosses PCIe: the scratch is
        reallocated whenever the row count changes, every step for a peer whose ghosts change)."""
        a = cuda.device_array(shape, dtype=self.dtype)
        _fill[blocks(a.size), BLOCK](a.reshape(a.size), a.size, self.dtype.type(initial))
        return a

    # -- host <-> device ---------------------------------------------------------------------------
    def transfer(self) -> dict:
        return self.traffic.summary()

    def walls_moved(self):
        """The moving walls' rows and velocities (motion.py) to the device: a few hundred bytes."""
        w = self.sim.walls
        self.traffic.up(np.ascontiguousarray(w.data), self.walls["wall_data"])
        self.traffic.up(np.ascontiguousarray(w.motion), self.walls["wall_motion"])

    def pull(self, state):
        """Bring the host mirror up to date (called by Simulation.state)."""
        if self.host_stale and not self.device_stale:
            self.d.download(state)
            self.host_stale = False

    def push_if_needed(self):
        if self.device_stale:
            state = self.sim._state
            self.d.upload(state)
            self.device_stale = False
        self.scratch.resize(self.d.n)

    def carried_names(self) -> tuple:
        self.push_if_needed()
        return SORTED + tuple(state_fields.EXTRA_PREFIX + k for k in self.d.extra_names)

    def _selected(self, flags, n: int):
        """Device int64 array of the rows i < n whose flag is 1, in order (flags is scanned in place)."""
        if n == 0:
            return cuda.device_array(0, dtype=np.int64)
        inclusive_scan(flags, n)
        count = int(self.traffic.down(flags[n - 1:n])[0])
        rows = cuda.device_array(count, dtype=np.int64)
        if count:
            _selected_rows[blocks(n), BLOCK](flags, n, rows)
        return rows

    def rows_of(self, names, rows, renumber: bool = True) -> dict:
        """The rows a halo message carries, gathered on the device: only they cross PCIe."""
        self.push_if_needed()
        if renumber:
            now = self.grid.sorted_rows(rows)
        else:
            rows = np.ascontiguousarray(rows, dtype=np.int64)
            now = self.traffic.up(rows) if len(rows) else cuda.device_array(0, dtype=np.int64)
        m = now.shape[0]
        out = {name: cuda.device_array((m,) + self.array(name).shape[1:], dtype=self.array(name).dtype)
               for name in names}
        gather_rows(now, m, [self.array(name) for name in names], [out[name] for name in names])
        return {name: self.traffic.down(a) for name, a in out.items()}

    def _zone_codes(self, dec, rank: int, neighbours) -> tuple:
        """(owner, mask, flags): decomposition.zone_code of every owned row, on the device; flags[i] = 1
        where row i leaves this peer or is a neighbour's ghost."""
        self.push_if_needed()
        n = self.d.n_owned
        g = self.grid
        *tables, reach = decomposition.zone_tables(dec, rank, neighbours)
        cuts, dims, boxes, _, periodic = [self.traffic.up(t) for t in tables]
        owner, mask, flags = (cuda.device_array(max(n, 1), dtype=np.int64) for _ in range(3))
        if n:
            _zone_kernel()[blocks(n), BLOCK](self.d.x, n, g.d_origin, g.d_inv_cell, g.d_ncell, rank, cuts, dims,
                                             boxes, periodic, reach, owner, mask, flags)
        return owner, mask, flags

    def zone_rows(self, dec, rank: int, neighbours) -> tuple:
        """zone_code of every owned row on the device; only the zone's rows, owners and masks come back."""
        owner, mask, flags = self._zone_codes(dec, rank, neighbours)
        rows = self._selected(flags, self.d.n_owned)
        m = rows.shape[0]
        if not m:
            return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
        picked = {"owner": cuda.device_array(m, dtype=np.int64), "mask": cuda.device_array(m, dtype=np.int64)}
        gather_rows(rows, m, [owner, mask], [picked["owner"], picked["mask"]])
        return self.traffic.down(rows), self.traffic.down(picked["owner"]), self.traffic.down(picked["mask"])

    def split_rows(self, dec, rank: int, neighbours) -> tuple:
        """zone_code of every owned row on the device, compacted there into the interior and the
        boundary rows (two counts cross PCIe)."""
        key = (dec, rank, tuple(neighbours))
        if self._split is None or self._split[0] != key:
            _, _, boundary = self._zone_codes(dec, rank, neighbours)  # after exchange 1 every owned row stays
            n = self.d.n_owned
            interior = cuda.device_array(max(n, 1), dtype=np.int64)
            if n:
                _complement[blocks(n), BLOCK](boundary, n, interior)
            self._split = (key, self._selected(interior, n), self._selected(boundary, n))
        return self._split[1], self._split[2]

    def rebuild(self, leaving, owned_in: dict, ghosts_in: dict):
        """The kept owned rows compacted on the device; only migrants and ghosts cross PCIe."""
        self.push_if_needed()
        d = self.d
        n_old = d.n_owned
        leaving = np.ascontiguousarray(leaving, dtype=np.int64)
        flags = cuda.device_array(max(n_old, 1), dtype=np.int64)
        if n_old:
            _fill[blocks(n_old), BLOCK](flags, n_old, 1)
        if len(leaving):
            _set_at[blocks(len(leaving)), BLOCK](flags, self.traffic.up(leaving), len(leaving), 0)
        kept = self._selected(flags, n_old)
        n_kept, m_in, g_in = kept.shape[0], len(owned_in["id"]), len(ghosts_in["id"])
        n_new = n_kept + m_in + g_in
        names = self.carried_names()
        new = {}
        for key in names:
            src = self.array(key)
            new[key] = cuda.device_array((n_new,) + src.shape[1:], dtype=src.dtype)
        gather_rows(kept, n_kept, [self.array(key) for key in names], [new[key] for key in names])
        for key in names:
            for lo, part in ((n_kept, owned_in[key]), (n_kept + m_in, ghosts_in[key])):
                if len(part):
                    self.traffic.up(np.ascontiguousarray(part, dtype=new[key].dtype), new[key][lo:lo + len(part)])
        for key in names:
            d.arrays[key[len(state_fields.EXTRA_PREFIX):] if key.startswith(state_fields.EXTRA_PREFIX) else key] = new[key]
        for name in state_fields.DERIVED:
            d.arrays[name] = self.allocate((n_new,) + state_fields.ROW_SHAPE[name], 0.0)
        d.n = n_new
        d.n_owned = n_kept + m_in
        self.device_stale = False
        self.host_stale = True
        self.scratch.resize(n_new)

    def set_rows(self, values: dict, rows):
        """Received rows (a neighbour's ghosts) written on the device: only they cross PCIe."""
        self.push_if_needed()
        now = self.grid.sorted_rows(rows)
        m = now.shape[0]
        if m:
            pairs = [a for name, v in values.items()
                     for a in (self.traffic.up(np.ascontiguousarray(v, dtype=self.array(name).dtype)), self.array(name))]
            scatter_kernel(tuple(a.ndim for a in pairs[::2]))[blocks(m), BLOCK](now, m, *pairs)
        self.host_stale = True

    def begin(self):
        self.push_if_needed()
        self.host_stale = True

    def n_owned(self):
        return self.d.n_owned

    def ghost_rows(self):
        """Counted on the device: no row number crosses PCIe."""
        m = self.d.n - self.d.n_owned
        rows = cuda.device_array(m, dtype=np.int64)
        if m:
            _count_from[blocks(m), BLOCK](self.d.n_owned, m, rows)
        return rows

    def array(self, name):
        d = self.d
        if name in FIELDS or name == "kappa":
            return d.arrays[name]
        if name.startswith(state_fields.EXTRA_PREFIX):
            return d.arrays[name[len(state_fields.EXTRA_PREFIX):]]
        if name == "rho_c":  # the carried density; unused (a placeholder row) with summation density
            return d.arrays["density"] if self.model.continuity else self.scratch.drho
        if name in self.scratch.arrays:
            return self.scratch.arrays[name]
        if name == "nbr":
            return self.grid.d_nbr
        if name == "counts":
            return self.grid.d_counts
        if name == "grad_w":  # the GPU recomputes grad W_ij (model.pair_gradients is off): a placeholder
            if self._no_pairs is None:
                self._no_pairs = cuda.device_array((3, 1, 1), dtype=self.dtype)
            return self._no_pairs
        if name == "cells":
            return self.grid.host.cells
        if name in ("cell_begin", "cell_end"):
            return getattr(self.grid, name)
        return self.walls[name]

    def launch(self, stage, choices, n, rows, arguments, wait):
        """One thread per owned row (or per row of ``rows``); the stage's reductions come back as
        numbers. Without reductions and with ``wait=False`` it returns at once: the host waits for a
        halo's messages while the device runs the interior rows."""
        slots = reduction_slots(stage.reduce)
        kinds = [t for t in ("int64", "float64") if any(typ == t for typ, _ in slots)]
        for t in kinds:
            zero(self.out[t])
        if n:
            KERNELS[stage.name](*choices)[blocks(n), BLOCK](n, rows, *arguments, *(self.out[t] for t in kinds))
        if not stage.reduce:
            if wait:
                cuda.synchronize()
            return None
        got = {t: self.traffic.down(self.out[t]) for t in kinds}
        values = [int(got[t][j]) if t == "int64" else float(got[t][j]) for t, j in slots]
        return values[0] if len(values) == 1 else tuple(values)

    def bin(self):
        """x -> (cell, id) order, and the neighbour lists unless the passes walk the cells."""
        self._split = None  # the interior and boundary rows of the new order, when a halo asks
        self.begin()
        if self.model.neighbours == "walk":
            self.grid.sort(self.d)
        else:
            self.grid.bin(self.d)
        cuda.synchronize()


def example_params(dtype: str):
    """A Params of precision ``dtype`` (f32, f64) with placeholder values: what a kernel's signature
    is typed from (its values do not matter)."""
    from sphcore.params import make_params
    return make_params(np.float32 if dtype == "f32" else np.float64, H=1.0, h=0.5, s_w=1.0, s_g=1.0, s_l=1.0,
                       w0=1.0, rho0=1000.0, c0=10.0, clamp_negative=True, alpha=0.1, mu=0.0, gravity=(0.0, -9.81, 0.0),
                       external=(0.0, 0.0, 0.0), central_omega2=1.0, central=(0.0, 0.0, 0.0), period=(0.0, 0.0, 0.0),
                       xsph_eps=0.0, shift_a=1.0, sigma=0.0, st_threshold=0.0, vorticity_eps=0.0, restitution=0.0,
                       friction=0.0, wall_gap=0.0, dx=0.5, inv_s=1.0, dim3=True, wall_table_end=1.0, dfsph_d0=1.0,
                       dfsph_omega=0.5, delta_hc0=1.0, wall_nu=0.0, p_background=0.0)


def argument_types(dtype: str) -> dict:
    """The numba type of every stage argument (stages.ARGUMENTS and stages.SCRATCH) in precision
    ``dtype``: the PTX signatures are generated from the declarations."""
    from numba import types
    from sphcore.stages import SCRATCH

    f = types.float32 if dtype == "f32" else types.float64
    real = np.float32 if dtype == "f32" else np.float64
    cells = grid_mod.Cells(*(real(1.0),) * 9, 1, 1, 1, False, False, False, real(1.0), 1, 1, 1, 27)
    prm = example_params(dtype)
    by_kind = {"params": numba.typeof(prm), "float": f, "int": types.int64, "bool": types.boolean, "vec": types.Array(f, 2, "C"),
               "row": types.Array(f, 1, "C"), "nbr": types.Array(types.int32, 2, "F"),
               "pairs": types.Array(f, 3, "C"),
               "counts": types.Array(types.int32, 1, "C"), "cells": numba.typeof(cells),
               "cell_rows": types.Array(types.int64, 1, "C"), "cell_flags": types.Array(types.uint8, 1, "C"),
               "kinds": types.Array(types.int32, 1, "C"),
               "table": types.Array(f, 2, "C"), "terms64": types.Array(types.float64, 1, "C")}
    out = {name: by_kind[kind] for name, (kind, _) in ARGUMENTS.items()}
    out.update({s.name: by_kind["row" if s.components == 1 else "vec"] for s in SCRATCH})
    out["n"] = types.int64
    out["rows"] = types.Array(types.int64, 1, "C")
    out["out_ints"] = types.Array(types.int64, 1, "C")
    out["out_reals"] = types.Array(types.float64, 1, "C")
    return out


def stage_signature(stage, dtype: str) -> tuple:
    """The argument types of ``stage``'s generated kernel (n, rows, its arguments, its reduction outputs)."""
    t = argument_types(dtype)
    slots = reduction_slots(stage.reduce)
    outs = tuple(name for t, name in (("int64", "out_ints"), ("float64", "out_reals")) if any(typ == t for typ, _ in slots))
    return tuple(t[a] for a in ("n", "rows", *stage.arguments, *outs))


_F64 = re.compile(r"^\s*(?:@!?%p\d+\s+)?[a-z]+(?:\.[a-z0-9]+)*\.f64\b", re.M)  # an instruction typed .f64


def float64_instructions(ptx: str) -> int:
    """The number of float64 instructions in a PTX text (arithmetic, moves, conversions to or from
    float64, comparisons: every instruction whose type suffix is .f64), not counting declarations."""
    return len(_F64.findall(ptx))


def _binning_signatures(t) -> dict:
    """{label: (kernel, PTX signature)} of the neighbour-list and binning kernels."""
    from numba import types
    f, v1, v2, nbr = t["dt"], t["rho"], t["x"], t["nbr"]
    i1, i8v, i8m = t["counts"], types.Array(types.int64, 1, "C"), types.Array(types.int64, 2, "C")
    n = types.int64
    cell_keys, scatter, sort_bins, cell_ranges = _binning_kernels()
    sigs = {}
    for periodic in CHOICES["periodic"][0]:
        sigs[f"neighbours periodic={periodic}"] = (
            _neighbour_kernel(periodic), (n, v2, types.boolean, i8v, i8v, v1, v1, v1, i8v, n, v1, f, nbr, i1))
    sigs.update({
        "cell_keys": (cell_keys, (v2, n, n, v1, v1, i8v, i8v, i8v, i1)),
        "scatter": (scatter, (i8v, n, i8v, i8v)),
        "sort_bins": (sort_bins, (n, i8v, i8v, i8v)),
        "cell_ranges": (cell_ranges, (n, i8v, i8v, i8v, i1)),
        "max_int": (_max_int, (i1, n, i1, n)),
        "fill_real": (_fill, (v1, n, f)),
        "inverse_permutation": (_inverse_permutation, (i8v, n, i8v)),
        "compose": (_compose, (i8v, i8v, n, i8v)),
        "fill_int64": (_fill, (i8v, n, types.int64)),
        "set_at": (_set_at, (i8v, i8v, n, types.int64)),
        "selected_rows": (_selected_rows, (i8v, n, i8v)),
        "complement": (_complement, (i8v, n, i8v)),
        "zone": (_zone_kernel(), (v2, n, v1, v1, i8v, n, i8m, i8v, i8m, i8v, n, i8v, i8v, i8v)),
        "scatter_rows": (scatter_kernel((1, 2)), (i8v, n, v1, v1, v2, v2)),
        "gather": (gather_kernel(tuple(1 + len(state_fields.ROW_SHAPE[f]) for f in SORTED)),
                   (i8v, n, *(a for f in SORTED for a in ((i8v,) * 2 if f == "id" else (t[f],) * 2)))),
        "scan_chunks": (_scan_chunks, (i8v, n, n, i8v)),
    })
    return sigs


def compile_all(dtype="f32", cc=(9, 0), stages=None, combinations=covering_choices, binning=True):
    """Compile the kernels of ``stages`` (default: all) for every choice combination that
    ``combinations(stage)`` lists (default: stages.covering_choices, every value of every choice),
    and (``binning``) the binning kernels, to PTX for compute capability ``cc`` without running them
    (needs NVVM, not a GPU): proves the shared row functions are valid CUDA. Returns {kernel label:
    PTX text}."""
    t = argument_types(dtype)
    sigs = {}
    for stage in (STAGES if stages is None else stages):
        signature = stage_signature(stage, dtype)
        for combo in combinations(stage):
            label = stage.name + "".join(f" {c}={v}" for c, v in combo.items())
            sigs[label] = (KERNELS[stage.name](*(combo[c] for c in stage.choices)), signature)
    if binning:
        sigs.update(_binning_signatures(t))
    # Device functions called from a kernel (the non-inlined wall functions) are compiled for the
    # current device's compute capability; without a GPU there is none, so answer ``cc`` for it.
    import types as pytypes
    import numba.cuda.dispatcher as cuda_dispatcher
    real = cuda_dispatcher.get_current_device
    if not cuda.is_available():
        cuda_dispatcher.get_current_device = lambda: pytypes.SimpleNamespace(compute_capability=cc)
    try:
        return {name: cuda.compile_ptx(disp.py_func, sig, cc=cc)[0] for name, (disp, sig) in sigs.items()}
    finally:
        cuda_dispatcher.get_current_device = real
