"""The first of the package's modules a local worker imports when the command line chose full-width SIMD
vectors for itself (``Runtime.wide_vectors``; :mod:`lunaralbedo.simd`): the workers' kernels then compile
for the CPU features of the process that started them.

That is one vector width for the whole run (the bytes are the same at either width,
``tests/test_simd.py``) and one set of numba cache entries: cached kernels are keyed by the CPU features,
so workers left at numba's own choice compiled every kernel a second time on a first run.  The
workers run on this machine (the forkserver's forks, or spawned interpreters), so the host's features
are theirs.  Importing it changes the importing process; only the worker start imports it.
"""
from __future__ import annotations

from .. import simd

#: The features set in this worker (None: numba's target was already made, or the CPU has no AVX-512).
FEATURES = simd.apply({})
