"""Workers on the nodes of ``$PBS_NODEFILE`` — the legacy way of spreading a run over a PBS job.

PhotometryTK ran GNU parallel over ssh to every host listed in ``PBS_NODEFILE``
(the PhotometryTK manual, section 4), NUM_PROCESSES processes per node.  Here the same file
starts a Dask scheduler on this node and ``NUM_PROCESSES`` Dask worker processes on
every listed node: the local node directly, the others through a remote shell
(``ssh -o BatchMode=yes`` by default; ``Runtime.remote_shell``, on the command line
``LUNARALBEDO_REMOTE_SHELL``, names another launcher such as ``rsh`` or ``ssh -i KEY``; it is
called as ``SHELL HOST COMMAND...``).  The node file is used only when asked for
(``Runtime.nodefile``; ``solve --nodefile "$PBS_NODEFILE"``), never because the variable is set.
The nodes must share the file system, as the legacy program required.
"""
from __future__ import annotations

import os
import shlex
import socket
import subprocess
import sys
from pathlib import Path

from ..errors import LunarAlbedoError
from ..runtime import REMOTE_SHELL
from .workers import worker_config, worker_env

_LOCAL_NAMES = {"localhost", "127.0.0.1", socket.gethostname(), socket.getfqdn()}


def pbs_nodes(nodefile: str | os.PathLike | None) -> list[str]:
    """Unique host names of a PBS node file (one per line, as PBS writes it), in order; none without a file."""
    path = nodefile
    if not path:
        return []
    try:
        lines = Path(path).read_text().split()
    except OSError as exc:
        raise LunarAlbedoError(f"{path}: cannot read PBS_NODEFILE: {exc}") from None
    return list(dict.fromkeys(h.strip() for h in lines if h.strip()))


class _WorkerProcesses:
    """The launcher processes of the remote workers; closing terminates them."""

    def __init__(self, procs: list[subprocess.Popen]):
        self.procs = procs

    def close(self) -> None:
        for p in self.procs:
            if p.poll() is None:
                p.terminate()
        for p in self.procs:
            try:
                p.wait(timeout=10)
            except subprocess.TimeoutExpired:
                p.kill()


def nodefile_client(hosts: list[str], processes_per_node: int, timeout: float = 120.0, remote_shell: str = REMOTE_SHELL,
                    tuned: bool = True):
    """Start a scheduler here and workers on ``hosts`` (``remote_shell HOST COMMAND...`` for the others than this
    one); return ``(client, [owned objects])``.  ``tuned``: the workers get :func:`~.workers.worker_env`'s tuning."""
    from distributed import Client, LocalCluster

    with worker_config(tuned):  # the scheduler's settings (the workers get theirs from worker_env)
        cluster = LocalCluster(n_workers=0, host="0.0.0.0", scheduler_port=0, dashboard_address=None, silence_logs=40)
    port = cluster.scheduler_address.rsplit(":", 1)[1]
    address = f"tcp://{socket.getfqdn()}:{port}"
    shell = shlex.split(remote_shell)
    worker = [
        "env", *(f"{k}={v}" for k, v in worker_env(tuned).items()),
        sys.executable, "-m", "distributed.cli.dask_worker", address,
        "--nworkers", str(processes_per_node), "--nthreads", "1",
        "--no-dashboard", "--death-timeout", "60",
    ]
    procs = []
    for host in hosts:
        cmd = worker if host in _LOCAL_NAMES else [*shell, host, *(shlex.quote(w) for w in worker)]
        procs.append(subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True))
    owned = _WorkerProcesses(procs)
    client = Client(cluster)
    try:
        client.wait_for_workers(processes_per_node * len(hosts), timeout=timeout)
    except Exception as exc:  # noqa: BLE001 - report which nodes did not come up
        failed = [h for h, p in zip(hosts, procs) if p.poll() is not None]
        owned.close()
        client.close()
        cluster.close()
        raise LunarAlbedoError(
            f"workers on the node file's hosts did not start within {timeout:.0f} s"
            f"{' (launcher exited on: ' + ', '.join(failed) + ')' if failed else ''}: {exc}; "
            f"check that `{' '.join(shell)} HOST` works without a password, or set LUNARALBEDO_REMOTE_SHELL"
        ) from None
    return client, [owned, cluster]
