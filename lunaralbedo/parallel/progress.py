"""Progress of long tile tasks a block of rows at a time, in this process.

The executors' bars count tasks (tiles); a run of one big tile would show 0/1 for minutes.
The tile tasks call :data:`ROWS` ``.advance(rows)`` after each block of rows they finish
(prepare, iterate, finalise); when the solver runs its tiles in this process with progress
on, it starts a second bar over the rows of all tiles for each pass.  In Dask workers (other
processes) no bar is started and ``advance`` does nothing.
"""
from __future__ import annotations

import threading

from tqdm.auto import tqdm


class RowProgress:
    """A bar over rows of tiles, advanced from any thread of this process; a no-op until :meth:`start`."""

    def __init__(self):
        self._bar = None
        self._lock = threading.Lock()

    def start(self, desc: str, total: int) -> None:
        self.stop()
        self._bar = tqdm(total=total, desc=f"{desc} (rows)", unit="row", leave=False)

    def advance(self, rows: int) -> None:
        bar = self._bar
        if bar is not None:
            with self._lock:
                bar.update(rows)

    def stop(self) -> None:
        bar, self._bar = self._bar, None
        if bar is not None:
            bar.close()


#: This process's row bar (see the module docstring).
ROWS = RowProgress()
