"""Fresh episodes drawn inside the compiled step, from the numpy generator's own stream.

An autoresetting vector env draws a finished entry's initial state and episode length in the
middle of a step. The numpy core does it with its ``Generator``:
``rng.uniform(low, high, size=(m, n))`` (each value ``low + (high - low) * next_double``, rows in
order), redrawing the rows where ``avoid`` holds at step 0 (:func:`asap_dsl.sampling.initial_states`),
then ``rng.integers(kmin, kmax + 1, size=m)`` (Lemire's method on the bit generator's
``next_uint32``). The generated code does the same through the bit generator's C interface (its
state and function addresses, which ``numpy.random.BitGenerator.ctypes`` gives), so the stream,
the values and the generator's state afterwards are numpy's to the bit (the tests check it).
Passing the ``Generator`` object itself to numba would do the same but costs tens of
microseconds per call to unbox.
"""

from __future__ import annotations

import ctypes

import numpy as np

#: Calls through the bit generator's function pointers (addresses passed as int64).
INTRINSICS = '''

def _bitgen_call(ret):
    @intrinsic
    def call(typingctx, fn, state):
        def codegen(context, builder, signature, args):
            fnty = llir.FunctionType(ret[1], [llir.IntType(8).as_pointer()])
            f = builder.inttoptr(args[0], fnty.as_pointer())
            return builder.call(f, [builder.inttoptr(args[1], llir.IntType(8).as_pointer())])
        return ret[0](types.int64, types.int64), codegen
    return call


_next_double = _bitgen_call((types.float64, llir.DoubleType()))
_next_uint32 = _bitgen_call((types.uint32, llir.IntType(32)))
'''


def pointers(rng: np.random.Generator) -> tuple[int, int, int]:
    """(state, next_double, next_uint32) addresses of ``rng``'s bit generator (valid while it lives)."""
    c = rng.bit_generator.ctypes
    return (int(c.state_address), ctypes.cast(c.next_double, ctypes.c_void_p).value,
            ctypes.cast(c.next_uint32, ctypes.c_void_p).value)


def uniform_row(dst: str, low: np.ndarray, high: np.ndarray, ind: str) -> list[str]:
    """Lines drawing one row ``dst[i]`` as numpy's ``uniform(low, high)`` does (``high - low``
    computed by numpy first, as there)."""
    span = np.subtract(high, low)
    return [f"{ind}{dst.format(i=i)} = {float(lo)!r} + {float(s)!r} * _next_double(RD, RS)"
            for i, (lo, s) in enumerate(zip(low, span))]


def bounded_integer(dst: str, low: int, high: int, ind: str) -> list[str]:
    """Lines drawing ``dst`` as numpy's ``integers(low, high + 1)`` for one value (int64, a range
    below 2**32: Lemire's rejection on ``next_uint32``, numpy's ``buffered_bounded_lemire_uint32``)."""
    r = int(high) - int(low)
    if r == 0:  # numpy draws nothing
        return [f"{ind}{dst} = {int(low)}"]
    if not 0 < r < 0xFFFFFFFF:
        from .exprs import NotCovered

        raise NotCovered(f"episode lengths {low}..{high}: a range beyond 32 bits")
    excl = r + 1
    threshold = (0xFFFFFFFF - r) % excl
    U = "np.uint64"
    return [f"{ind}_m = {U}(_next_uint32(RU, RS)) * {U}({excl})",
            f"{ind}if (_m & {U}(0xFFFFFFFF)) < {U}({excl}):",
            f"{ind}    while (_m & {U}(0xFFFFFFFF)) < {U}({threshold}):",
            f"{ind}        _m = {U}(_next_uint32(RU, RS)) * {U}({excl})",
            f"{ind}{dst} = {int(low)} + np.int64(_m >> {U}(32))"]
