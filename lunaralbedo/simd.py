"""Full-width SIMD vectors for the compiled kernels on AVX-512 CPUs.

LLVM tunes its code for Intel's AVX-512 cores (Skylake-X to Sapphire Rapids; it names this
project's machine ``rocketlake``) with the ``prefer-256-bit`` setting: it vectorises with 256-bit
registers although 512-bit ones are there, because on the first of those cores wide vectors
lowered the clock.  The iterate kernel's lanes of Q and the normal equations are float64 sums
four to a 256-bit register; eight to a register, the iterate stage of a one-CPU solve of
``make bench``'s strip took 4.80-4.92 ns per observation and pass against 5.12-5.13, back to back
(docs/performance-history.md, section 0m).

numba compiles for the CPU features of its configuration (``NUMBA_CPU_FEATURES`` when set, else
the host's), read once, when it makes its CPU target (at the first ``@njit(cache=True)`` a module
defines).  :func:`apply` sets them to the host's features with ``-prefer-256-bit`` in this
process; the command line calls it as a command starts, before any of the package's modules defines
a kernel (``cli/_common.reports_errors``); importing :mod:`lunaralbedo` does not (the library changes
nothing process-wide), and local workers follow it (``Runtime.wide_vectors``,
:mod:`lunaralbedo.parallel.worker_vectors`).  It changes no result: there
is no fast-math, no contraction into fused multiply-adds and no reassociation, so each lane does
the same IEEE operations at either width (``tests/test_simd.py`` compares a solve's bytes at both).

Left alone, with nothing set, where the user chose: ``NUMBA_CPU_NAME`` or ``NUMBA_CPU_FEATURES``
set, ``LUNARALBEDO_VECTOR_BITS=256`` (this module's switch), a CPU without AVX-512F, or numba's CPU
target already made in this process (numba used before the command started: the kernels then
compile for the features it chose).
"""
from __future__ import annotations

import sys
from typing import Callable, Mapping

#: This module's switch: ``256`` keeps LLVM's own choice of vector width; unset or ``512``: full width.
SWITCH = "LUNARALBEDO_VECTOR_BITS"
#: numba's variables: where the user set one of them, nothing is changed.
NUMBA_VARIABLES = ("NUMBA_CPU_NAME", "NUMBA_CPU_FEATURES")
#: The LLVM feature this module turns off.
NARROW = "prefer-256-bit"


def wide_features(environ: Mapping[str, str], host_features: Callable[[], str]) -> str | None:
    """The CPU features for numba (the host's with ``-prefer-256-bit``), or None to leave numba alone.

    ``host_features()`` returns LLVM's comma-separated ``+name``/``-name`` features of the host;
    it is called only when needed.  Raises ValueError for a switch that is neither 256 nor 512."""
    bits = environ.get(SWITCH, "").strip()
    if bits not in ("", "256", "512"):
        raise ValueError(f"{SWITCH}={bits!r}: expected 256 or 512")
    if bits == "256" or any(name in environ for name in NUMBA_VARIABLES):  # set at all, even empty: the user's
        return None
    features = host_features()
    if "+avx512f" not in features.split(","):
        return None
    return f"{features},-{NARROW}"


def _numba_target_made() -> bool:
    """Whether numba already made its CPU target in this process (its features are then fixed)."""
    registry = sys.modules.get("numba.core.registry")
    target = getattr(registry, "cpu_target", None)
    return target is not None and "_toplevel_target_context" in vars(target)


def _host_features() -> str:
    import llvmlite.binding as llvm  # numba's own dependency (the package imports numba anyway)

    try:
        return llvm.get_host_cpu_features().flatten()
    except RuntimeError:  # LLVM cannot tell on this platform (numba then uses none either)
        return ""


def apply(environ: Mapping[str, str]) -> str | None:
    """Have numba compile for full-width vectors where :func:`wide_features` says so and its CPU
    target is not made yet; returns the features set (None: nothing changed).

    Sets numba's configuration in this process only, not ``NUMBA_CPU_FEATURES``: a child
    process started on another machine (a batch system may pass the environment on) must not
    inherit this CPU's features; each process that imports :mod:`lunaralbedo` decides for its
    own CPU.  numba's CPU target is made at once, with these features, so that no later reload
    of numba's configuration (numba reads its environment variables again when they change)
    undoes them."""
    if _numba_target_made():
        return None
    features = wide_features(environ, _host_features)
    if features is not None:
        from numba.core import config
        from numba.core.registry import cpu_target

        config.CPU_FEATURES = features
        cpu_target.target_context  # noqa: B018  (made now: its code generator reads the features once)
    return features
