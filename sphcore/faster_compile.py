"""Faster compilation: two of numba's compiler passes copy data in quadratic time; here they copy it
in linear time, producing the same objects, so the compiled code is the same.

Compiling is most of a cold test run and of a user's first run of a scene (each set of stage
drivers takes a minute or more on these 2 cores), and two copies made most of it
(py-spy and cProfile, 2026-12-07):

1. **The inliner's block copies.** Every physics row function is inlined by numba at its IR level
   (``inline="always"``), and the inliner (``InlineWorker.inline_ir``, numba 0.68 and numba-cuda
   0.30) copies the callee's IR block by block, each block with a deep copy of its own: every block
   drags the function's one ``Scope`` along, and with it a copy of every variable of the function,
   so a callee of B blocks and V variables costs B x V copies instead of B + V, twice per call site.
   It was 19 of the 30 s of compiling the default force kernel to PTX. Here the blocks of one copy
   share one deep-copy memo, which is what copying them in one ``copy.deepcopy(blocks)`` gives: the
   scope is copied once, each variable once, and the inliner renames the callee's variables in that
   scope as it did in the first block's copy before.
2. **Copy propagation's fixed point** (``ir_utils.copy_propagate``, run by the parallel drivers'
   passes on the whole inlined body) deep-copies its table of copies (block -> set of (name, name))
   on every round to compare the next one with it: a fifth of compiling a CPU driver. The sets hold
   tuples of strings, which ``copy.deepcopy`` returns unchanged, so copying each set gives the same
   table. The alias analysis's map (name -> set of names) is copied the same way.

Only the ``copy`` name of those two numba modules is replaced (by ``_Copies``, which falls through to
the ``copy`` module for anything else); the inliner's memo is shared only while ``inline_ir`` runs.
tests/test_faster_compile.py compiles kernels with and without it and compares their PTX and
machine code. ``SPH_FASTER_COMPILE=0`` leaves numba as it is.
"""
import copy
import functools
import os


def _flat_sets(x) -> bool:
    """Whether ``x`` is a dict of sets whose members are strings, integers or tuples of them: what
    ``copy.deepcopy`` copies as ``{k: set(v)}`` (it returns such members unchanged). Plain loops:
    this check runs over every member of the table on every round."""
    if type(x) is not dict:
        return False
    for members in x.values():
        if type(members) is not set:
            return False
        for m in members:
            t = type(m)
            if t is tuple:
                for a in m:
                    if type(a) is not str and type(a) is not int:
                        return False
            elif t is not str and t is not int:
                return False
    return True


class _Copies:
    """Stands in for the ``copy`` module in one numba module."""

    def __init__(self, block_type=None):
        self.block_type = block_type
        self.memos = None  # {id(scope): (scope, memo)} while the inliner runs; None otherwise

    def deepcopy(self, x, memo=None):
        if memo is None:
            if self.memos is not None and isinstance(x, self.block_type):
                scope = x.scope
                held = self.memos.get(id(scope))
                if held is None or held[0] is not scope:
                    held = self.memos[id(scope)] = (scope, {})
                return copy.deepcopy(x, held[1])
            if _flat_sets(x):
                return {k: set(v) for k, v in x.items()}
        return copy.deepcopy(x, memo)

    def __getattr__(self, name):  # copy.copy and anything else: the module's own
        return getattr(copy, name)


def _enabled() -> bool:
    return os.environ.get("SPH_FASTER_COMPILE", "1") != "0"


def _replace_copy(module, copies) -> bool:
    if getattr(module, "copy", None) is not copy:
        return False  # already done, or a numba that does not look as expected: left as it is
    module.copy = copies
    return True


def _share_block_memo(inliner_module, block_type) -> bool:
    worker = getattr(inliner_module, "InlineWorker", None)
    inline_ir = getattr(worker, "inline_ir", None)
    copies = _Copies(block_type)
    if inline_ir is None or not _replace_copy(inliner_module, copies):
        return False

    @functools.wraps(inline_ir)
    def inline_ir_sharing_one_memo(self, *args, **kwargs):
        outer, copies.memos = copies.memos, {}
        try:
            return inline_ir(self, *args, **kwargs)
        finally:
            copies.memos = outer

    worker.inline_ir = inline_ir_sharing_one_memo
    return True


def patch_cpu() -> bool:
    """numba's inliner and copy propagation (the CPU kernels); True if both were patched."""
    if not _enabled():
        return False
    from numba.core import inline_closurecall, ir, ir_utils
    return _share_block_memo(inline_closurecall, ir.Block) & _replace_copy(ir_utils, _Copies())


def patch_cuda() -> bool:
    """numba-cuda's twins of the same (the CUDA kernels and their PTX)."""
    if not _enabled():
        return False
    from numba.cuda.core import inline_closurecall, ir, ir_utils
    return _share_block_memo(inline_closurecall, ir.Block) & _replace_copy(ir_utils, _Copies())
