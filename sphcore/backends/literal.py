"""Fast calls into numba functions whose leading arguments are compile-time literals, always into
the machine code of numba's on-disk cache.

The generated stage drivers hold their choices as module constants (``generate.cpu_source``) and
take no literals (``literal_dispatch(0)``); ``grid._build_neighbours`` still takes ``periodic`` as a
``numba.literally`` integer. numba finds a literal specialisation by raising and catching a typing
exception on *every* call, which costs ~0.1 s, and types every call's arguments; ``LiteralDispatch``
types them once per combination and then calls the compiled entry point directly (~10 us).

**Compiled in a helper process.** numba runs a kernel it has just compiled from its JIT engine and
caches it through a separate object-code path, and with the neighbour passes' reassociation
licence (``generate.FASTMATH``) the two schedule the sums differently: the process that compiled a
scene's kernels got other last bits than every later process that loaded them from the cache
(measured: the 2D dam break, 300 steps, x differed by up to 3e-16 in 196 of its 200 particles), so a
peer restarted after a fault, or a run resumed from a checkpoint, drifted from the run it continues.
Loading the cached code back into the compiling process does not help: its engine resolves the
symbols to the JIT's copies. So a specialisation missing from the cache is compiled by a helper
process (``python -m sphcore.backends.literal``, started at the first miss and kept for the
process's life), which saves it to the cache, and this process loads it from there like every other.
Every process then runs the same object code. Where the cache cannot be written the kernel is
compiled here, with a warning that runs are then reproducible only within this process. The helper
imports this process's code wherever it was started (sphcore/children.py) and refuses a module it
finds in another file than the asking process does: it would compile other sources than the
asking process's.

**Compiled once among processes.** The peers of a run started cold miss the same specialisations at
the same moment. A lock file per specialisation in the cache folder lets one of them compile it;
the others wait and load it (4 processes stepping configs/tiny.toml from an empty cache on 2 cores:
63 s instead of 123 s).
"""
import contextlib
import hashlib
import importlib
import importlib.util
import logging
import os
import pickle
import struct
import subprocess
import sys
import threading
import time
from pathlib import Path

import numba
import numpy as np
from numba.core import event, types
from numba.core.caching import NullCache

from sphcore.children import module_command, module_env

log = logging.getLogger("sph.compile")


class LiteralDispatch:
    def __init__(self, dispatcher, n_literals: int):
        self.dispatcher = dispatcher
        self.n_literals = n_literals
        self._entry = {}
        self.__doc__ = dispatcher.py_func.__doc__
        self.__name__ = dispatcher.py_func.__name__

    def __call__(self, *args):
        key = tuple(args[: self.n_literals]) + tuple(_cheap_type(a) for a in args[self.n_literals:])
        entry = self._entry.get(key)
        if entry is None:
            entry = self._entry[key] = self._compile(args)
        return entry(*args)

    def _compile(self, args):
        """The entry point of the specialisation for ``args``, loaded from the on-disk cache (compiled
        there by the helper process if missing)."""
        n = self.n_literals
        d = self.dispatcher
        sig = tuple(types.literal(v) for v in args[:n]) + tuple(numba.typeof(a) for a in args[n:])
        if sig not in d.overloads and not isinstance(d._cache, NullCache):
            if d._cache.load_overload(sig, d.targetctx) is None:
                # progress (launch/compiling.py) while compiling, or waiting for the process that does
                with event.trigger_event("numba:compile", data={"dispatcher": d, "args": sig, "return_type": None}):
                    with _compiling(d, sig):  # one process compiles it; the others wait, then load it
                        if d._cache.load_overload(sig, d.targetctx) is None:
                            _compile_elsewhere(d, sig)
        misses = d._cache_misses[sig]
        d.compile(sig)  # loads from the cache (or, where that failed, compiles here)
        if d._cache_misses[sig] > misses and not isinstance(d._cache, NullCache):
            _warn_compiled_here(self.__name__)
        return d.overloads[sig].entry_point


def _cheap_type(a):
    """A hashable stand-in for numba.typeof(a) that is cheap to compute (typeof costs ~5 us per
    argument, which adds up to milliseconds per step on small scenes)."""
    if isinstance(a, np.ndarray):
        return (a.dtype.str, a.ndim, a.flags.c_contiguous, a.flags.writeable)
    if isinstance(a, tuple):
        return (type(a), type(a[0]) if a else None)
    return type(a)


def literal_dispatch(n_literals: int):
    """Decorator: wrap a numba dispatcher whose first ``n_literals`` arguments are literals."""
    def wrap(dispatcher):
        return LiteralDispatch(dispatcher, n_literals)
    return wrap


# -- the helper process -----------------------------------------------------------------------------
_helper = None
_helper_lock = threading.Lock()
LOCK_WAIT_S = 1800.0  # the longest wait for another process's compile (a cold scene takes minutes)
_warned = False


def _where(dispatcher):
    """(module name, its file, attribute) by which the helper finds ``dispatcher``."""
    func = dispatcher.py_func
    module = sys.modules[func.__module__]
    return func.__module__, module.__file__, func.__name__


def _send(stream, payload: bytes):
    stream.write(struct.pack("<Q", len(payload)) + payload)
    stream.flush()


def _receive(stream):
    head = stream.read(8)
    if len(head) < 8:
        return None
    return stream.read(struct.unpack("<Q", head)[0])


@contextlib.contextmanager
def _compiling(dispatcher, sig):
    """Hold an exclusive lock on the cache's entry for (``dispatcher``, ``sig``) while it is compiled:
    processes that miss the same specialisation at once (the peers of a run started cold, test
    workers) compile it once between them instead of once each, and the others then load it. No
    lock where none can be taken (no fcntl, a cache folder that cannot be written, a file system
    without locks), and none after LOCK_WAIT_S: a holder that neither finishes nor dies (a stopped
    process) delays the others, it does not hang them; they then compile it themselves."""
    try:
        import fcntl
        key = hashlib.sha256(f"{dispatcher.py_func.__module__}.{dispatcher.py_func.__qualname__} {sig}".encode())
        # the empty lock files stay: removing one that another process has open would let two compile
        path = Path(dispatcher._cache.cache_path) / f"compiling-{key.hexdigest()[:20]}.lock"
        handle = open(path, "a+b")
    except (ImportError, OSError):
        yield
        return
    try:
        deadline = time.monotonic() + LOCK_WAIT_S
        while True:
            try:
                fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except BlockingIOError:  # another process compiles it
                if time.monotonic() > deadline:
                    log.warning("%s: waited %g s for another process to compile it; compiling it here",
                                dispatcher.py_func.__name__, LOCK_WAIT_S)
                    break
                time.sleep(0.05)
            except OSError:  # no locks here
                break
        yield
    finally:
        handle.close()  # and with it the lock


def _compile_elsewhere(dispatcher, sig):
    """Have the helper process compile ``dispatcher`` for ``sig`` into the on-disk cache; failures
    are logged (the caller then compiles in this process)."""
    global _helper
    with _helper_lock:
        try:
            if _helper is None or _helper.poll() is not None:
                # this process's code, not a folder of that name where it was started (sphcore/children.py)
                _helper = subprocess.Popen(module_command("sphcore.backends.literal"), env=module_env(),
                                           stdin=subprocess.PIPE, stdout=subprocess.PIPE)
            _send(_helper.stdin, pickle.dumps((*_where(dispatcher), sig)))
            answer = _receive(_helper.stdout)
        except (OSError, pickle.PicklingError, ValueError) as e:
            answer = f"the helper process could not be used: {e}".encode()
    if answer != b"ok":
        reason = "it exited" if answer is None else answer.decode(errors="replace")
        log.warning("%s: compiling in this process (the compile helper failed: %s)", dispatcher.py_func.__name__,
                    reason)


def _warn_compiled_here(name):
    global _warned
    if not _warned:
        _warned = True
        log.warning("%s was compiled in this process, not loaded from numba's cache: this run's last bits may "
                    "differ from other processes' (a restarted peer, a resumed run); see sphcore/backends/literal.py",
                    name)


def _same_file(a, b) -> bool:
    try:
        return a is not None and os.path.samefile(a, b)
    except OSError:
        return False


def _serve():
    """The helper: read (module, file, attribute, signature) requests, compile each into the cache."""
    stdin, stdout = sys.stdin.buffer, sys.stdout.buffer
    sys.stdout = sys.stderr  # nothing but answers on the pipe
    while True:
        request = _receive(stdin)
        if request is None:
            return
        try:
            name, path, attribute, sig = pickle.loads(request)
            module = sys.modules.get(name)
            if module is None:
                try:
                    module = importlib.import_module(name)
                except ImportError:  # a generated module: imported from its file, under its name
                    spec = importlib.util.spec_from_file_location(name, path)
                    module = importlib.util.module_from_spec(spec)
                    sys.modules[name] = module
                    spec.loader.exec_module(module)
            if not _same_file(getattr(module, "__file__", None), path):
                # it would compile other sources than the asking process's
                raise ImportError(f"{name} is {getattr(module, '__file__', None)} here, {path} in the asking process")
            target = getattr(module, attribute)
            target = getattr(target, "dispatcher", target)
            target.compile(sig)
            answer = b"ok"
        except Exception as e:  # reported to the parent, which compiles itself
            answer = f"{type(e).__name__}: {e}".encode()
        _send(stdout, answer)


if __name__ == "__main__":
    try:
        _serve()
    except KeyboardInterrupt:  # Ctrl-C reached the run's process group: the asking process stops too
        sys.exit(130)          # (no traceback on the user's terminal)
