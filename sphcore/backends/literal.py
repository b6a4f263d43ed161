"""Fast calls into numba functions whose leading arguments are compile-time literals.

Drivers take their choices (kernel, EOS, viscosity model...) as ``numba.literally`` integers, so
each scene compiles only the branches it uses. numba finds a literal specialisation by raising and
catching a typing exception on *every* call, which costs ~0.1 s; ``LiteralDispatch`` does that once
per combination and then calls the compiled entry point directly (~10 us).
"""
import numba
from numba.core import types


class LiteralDispatch:
    def __init__(self, dispatcher, n_literals: int):
        self.dispatcher = dispatcher
        self.n_literals = n_literals
        self._entry = {}
        self.__doc__ = dispatcher.py_func.__doc__
        self.__name__ = dispatcher.py_func.__name__

    def _key(self, args):
        return tuple(args[: self.n_literals]) + tuple(numba.typeof(a) for a in args[self.n_literals:])

    def __call__(self, *args):
        key = self._key(args)
        entry = self._entry.get(key)
        if entry is None:
            result = self.dispatcher(*args)  # compiles, or loads from the on-disk cache
            entry = self._find(key)
            self._entry[key] = entry
            return result
        return entry(*args)

    def _find(self, key):
        n = self.n_literals
        for sig, cres in self.dispatcher.overloads.items():
            lits = sig[:n]
            if all(isinstance(t, types.Literal) and t.literal_value == v for t, v in zip(lits, key[:n])) \
                    and tuple(sig[n:]) == key[n:]:
                return cres.entry_point
        raise RuntimeError(f"{self.__name__}: no compiled specialisation for {key}")


def literal_dispatch(n_literals: int):
    """Decorator: wrap a numba dispatcher whose first ``n_literals`` arguments are literals."""
    def wrap(dispatcher):
        return LiteralDispatch(dispatcher, n_literals)
    return wrap
