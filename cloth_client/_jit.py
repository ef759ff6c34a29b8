"""The numba decorators of every cloth kernel (solver, contact and avatar kernels alike).

Each kernel has a plain numpy reference beside it, in the same subpackage, and a test holds the
two equal. Kernels work in place on ``float64`` arrays and never allocate per particle. Small
helpers called per particle or per spring are compiled inline into their callers
(:data:`inline_kernel`: a call with array arguments costs more than the work they do); in hot loops
they take numbers rather than arrays where they can (an array handed to an inlined helper with
branches or loops costs an atomic reference-count increment and decrement per call, as much as the
arithmetic of a particle).

Speed-ups are kept bit-identical (re-running the quality sweep is expensive), which takes more than
the same formulas: with the ``contract`` and ``reassoc`` fast-math flags below, a product and the
sum using it become one FMA only when both are in one basic block, and the order in which a sum of
products is added may follow the order in which its operands were defined (loads in a loop body,
loop-carried values). Compare any change bitwise with the previous kernels.
"""

from __future__ import annotations

from numba import njit

__all__ = ["inline_kernel", "jit_kernel"]

#: numpy error model (no zero-division checks: every division is guarded by hand) and fast-math
#: flags that keep NaN/inf semantics, so a blow-up still shows as NaN instead of being optimised away.
jit_kernel = njit(cache=True, error_model="numpy", fastmath={"nsz", "arcp", "contract", "afn", "reassoc"})
#: The same compiled inline into its callers (small helpers called per particle: no call overhead).
inline_kernel = njit(cache=True, inline="always", error_model="numpy",
                     fastmath={"nsz", "arcp", "contract", "afn", "reassoc"})
