"""How a run uses the machine: memory budgets, how local workers start, where remote ones run.

A :class:`Runtime` is passed in (``solve(..., runtime=Runtime(block_mb=128))``, the same for
:func:`lunaralbedo.parallel.make_executor`); nothing under the package reads the environment.
The command line builds one from its environment variables (:meth:`Runtime.from_environ`, called
only by :mod:`lunaralbedo.cli`), the way ``rasterio.Env`` gathers GDAL's options in one object.

numba's vector width (``LUNARALBEDO_VECTOR_BITS``, :mod:`lunaralbedo.simd`) is the command line's
choice too: it is applied before any kernel compiles, process-wide, so it is not a field here.

None of these values changes a result: the outputs are the same bytes for any of them
(``tests/test_engine.py``, ``tests/test_scale.py``).

=================================  ==============================  ===========================================
variable (command line only)       field                           meaning
=================================  ==============================  ===========================================
``LUNARALBEDO_BLOCK_MB``           ``block_mb``                    working memory of a block of rows (MiB)
``LUNARALBEDO_BLOCK_ROWS``         ``block_rows``                  force the rows per block (tests, benchmarks)
``LUNARALBEDO_STACK_MEMORY_MB``    ``stack_memory_mb``             observations kept in memory between passes
``LUNARALBEDO_WORKER_START``       ``worker_start``                ``forkserver`` (Linux default) or ``spawn``
``LUNARALBEDO_REMOTE_SHELL``       ``remote_shell``                launcher of workers on node-file hosts
``--nodefile`` (e.g. $PBS_NODEFILE) ``nodefile``                   hosts to start workers on (only when given)
=================================  ==============================  ===========================================
"""
from __future__ import annotations

import shlex
from dataclasses import dataclass, replace
from typing import Mapping

from .errors import SettingsError

#: Default working memory of one block of a tile in the prepare and iterate steps (MiB).
BLOCK_MB = 384.0
#: Default memory for the observations a process keeps between iterations (MiB).
STACK_MEMORY_MB = 512.0
#: How a node file's remote workers are launched: ``SHELL HOST COMMAND...``.
REMOTE_SHELL = "ssh -o BatchMode=yes"
WORKER_STARTS = ("forkserver", "spawn")

#: environment variable -> (field, parser) for :meth:`Runtime.from_environ`.
VARIABLES = {
    "LUNARALBEDO_BLOCK_MB": "block_mb",
    "LUNARALBEDO_BLOCK_ROWS": "block_rows",
    "LUNARALBEDO_STACK_MEMORY_MB": "stack_memory_mb",
    "LUNARALBEDO_WORKER_START": "worker_start",
    "LUNARALBEDO_REMOTE_SHELL": "remote_shell",
}


@dataclass(frozen=True)
class Runtime:
    """Machine-use options of a run (none changes a result).

    Passed to :func:`lunaralbedo.engine.solve.solve` and
    :func:`lunaralbedo.parallel.make_executor`; frozen, validated on construction (change
    one with :meth:`but`).  The output bytes are the same for any of these values.

    Parameters
    ----------
    block_mb : float, default BLOCK_MB (384)
        Working memory of one block of rows of a tile in the prepare and iterate steps, MiB per worker.
    block_rows : int or None, default None
        Rows per block, overriding the budget (None: from ``block_mb``).
    stack_memory_mb : float, default STACK_MEMORY_MB (512)
        Observations a process keeps in memory between iterations, MiB; beyond it they are
        memory-mapped from the cache every pass.
    worker_start : {"forkserver", "spawn"} or None, default None
        How local worker processes start; None: ``forkserver`` on Linux, ``spawn`` elsewhere.
    remote_shell : str, default REMOTE_SHELL ("ssh -o BatchMode=yes")
        Command that starts a worker on a node-file host (called as ``SHELL HOST COMMAND...``).
    nodefile : str or None, default None
        A PBS node file: workers are started on every host it lists.  Only when given.
    tune_workers : bool, default True
        Tune glibc's malloc and NumPy's huge pages in the worker processes this run starts
        (:mod:`lunaralbedo.parallel.workers`); they are the run's own processes.  The command line
        leaves them alone where the user set ``MALLOC_*`` or ``NUMPY_MADVISE_HUGEPAGE`` variables.
    tune_process : bool, default False
        The same in this process, for tile tasks run in it (one worker, thread pools).  Off for
        library calls: a notebook's process is left as it was; the command line turns it on.
    wide_vectors : bool, default False
        Local worker processes compile the kernels for full-width SIMD vectors on AVX-512 CPUs
        (:mod:`lunaralbedo.parallel.worker_vectors`), as the command line does for its own process
        (:mod:`lunaralbedo.simd`), so the run uses one width and one set of cached kernels.  Off for
        library calls (numba's own choice everywhere); the command line sets it to its own choice.

    Raises
    ------
    SettingsError
        Exit 2: a value no run can use (``block_mb`` not > 0, ``block_rows`` < 1, a negative
        ``stack_memory_mb``, an unknown ``worker_start``, an empty ``remote_shell``).
    """

    block_mb: float = BLOCK_MB
    block_rows: int | None = None
    stack_memory_mb: float = STACK_MEMORY_MB
    worker_start: str | None = None
    remote_shell: str = REMOTE_SHELL
    nodefile: str | None = None
    tune_workers: bool = True
    tune_process: bool = False
    wide_vectors: bool = False

    def __post_init__(self):
        self.validate()

    def validate(self) -> None:
        """Check every field; called on construction.

        Raises
        ------
        SettingsError
            Naming the option (and its environment variable) with a value no run can use.
        """
        if not self.block_mb > 0:
            raise SettingsError(f"block_mb (LUNARALBEDO_BLOCK_MB) must be > 0, got {self.block_mb!r}")
        if self.block_rows is not None and self.block_rows < 1:
            raise SettingsError(f"block_rows (LUNARALBEDO_BLOCK_ROWS) must be >= 1, got {self.block_rows!r}")
        if not self.stack_memory_mb >= 0:
            raise SettingsError(f"stack_memory_mb (LUNARALBEDO_STACK_MEMORY_MB) must be >= 0, got {self.stack_memory_mb!r}")
        if self.worker_start is not None and self.worker_start not in WORKER_STARTS:
            raise SettingsError(f"LUNARALBEDO_WORKER_START must be one of {', '.join(WORKER_STARTS)}, "
                                f"got {self.worker_start!r}")
        if not shlex.split(self.remote_shell):
            raise SettingsError("remote_shell (LUNARALBEDO_REMOTE_SHELL) is empty")

    @property
    def block_bytes(self) -> float:
        """Working memory of one block, bytes (``block_mb`` MiB)."""
        return self.block_mb * 2**20

    @property
    def stack_bytes(self) -> int:
        """Memory for the observations kept between iterations, bytes (``stack_memory_mb`` MiB)."""
        return int(self.stack_memory_mb * 2**20)

    def but(self, **changes) -> "Runtime":
        """Return a copy with some fields changed.

        Parameters
        ----------
        **changes
            Fields of :class:`Runtime` and their new values.

        Returns
        -------
        Runtime
            The copy, validated.

        Raises
        ------
        SettingsError
            A new value no run can use.
        """
        return replace(self, **changes)

    @classmethod
    def from_environ(cls, environ: Mapping[str, str], **given) -> "Runtime":
        """Build the runtime the environment variables of :data:`VARIABLES` ask for.

        Called by the command line only (the library takes a :class:`Runtime`).

        Parameters
        ----------
        environ : Mapping of str to str
            The environment (``os.environ`` in the command line); unset or blank variables
            keep their field's default.
        **given
            Fields set by the caller (e.g. ``nodefile`` from ``--nodefile``); they win over
            the environment.

        Returns
        -------
        Runtime
            The runtime, validated.

        Raises
        ------
        SettingsError
            Exit 2: an unparsable or invalid value, naming the variable.
        """
        values: dict = {}
        for name, fld in VARIABLES.items():
            text = environ.get(name)
            if text is None or not text.strip():
                continue
            text = text.strip()
            try:
                if fld in ("block_mb", "stack_memory_mb"):
                    values[fld] = float(text)
                elif fld == "block_rows":
                    values[fld] = int(text)
                elif fld == "worker_start":
                    values[fld] = text.lower()
                else:
                    values[fld] = text
            except ValueError:
                raise SettingsError(f"{name}={text!r}: not a number") from None
        return cls(**{**values, **given})
