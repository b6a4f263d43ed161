"""Fast calls into numba functions whose leading arguments are compile-time literals.

Drivers take their choices (kernel, EOS, viscosity model...) as ``numba.literally`` integers, so
each scene compiles only the branches it uses. numba finds a literal specialisation by raising and
catching a typing exception on *every* call, which costs ~0.1 s; ``LiteralDispatch`` does that once
per combination and then calls the compiled entry point directly (~10 us).
"""
import numba
import numpy as np
from numba.core import types


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
            result = self.dispatcher(*args)  # compiles, or loads from the on-disk cache
            self._entry[key] = self._find(args)
            return result
        return entry(*args)

    def _find(self, args):
        n = self.n_literals
        wanted = tuple(numba.typeof(a) for a in args[n:])
        for sig, cres in self.dispatcher.overloads.items():
            lits = sig[:n]
            if all(isinstance(t, types.Literal) and t.literal_value == v for t, v in zip(lits, args[:n])) \
                    and tuple(sig[n:]) == wanted:
                return cres.entry_point
        raise RuntimeError(f"{self.__name__}: no compiled specialisation for {args[:n]} {wanted}")


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
