"""The first module the server of local workers imports (:mod:`.forkserver`), and the only place it is
imported: it tunes that server process as :data:`~.workers.MALLOC_ENV` and :data:`~.workers.NUMPY_ENV`
would at its start (``mallopt`` and NumPy's hugepage switch), so that every worker forked from it
inherits the tuning, without the solving process's own environment being touched.

Importing it changes the importing process; nothing else in the package does that on import.
"""
from __future__ import annotations

from .workers import tune_malloc, tune_numpy

TUNED = (tune_malloc(), tune_numpy())
