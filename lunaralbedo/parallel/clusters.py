"""Clusters to run workers on: local processes, an existing scheduler, PBS/Slurm batch jobs (dask-jobqueue).

Each function returns ``(client, [objects to close with it])``.
"""
from __future__ import annotations

import socket

from ..errors import ClusterError, LunarAlbedoError
from .workers import WORKER_ENV, worker_config


def _probe(address: str, timeout: float = 10.0) -> None:
    """Fail at once (:class:`ClusterError`) when nothing listens at a ``tcp://host:port`` address.

    Dask's client retries a refused connection until its 20 s timeout; a plain socket
    connect tells a closed port (refused), an unknown host or an unreachable one at once.
    Other address schemes (tls://, inproc://) are left to Dask.
    """
    scheme, sep, rest = address.partition("://")
    host, colon, port = rest.rpartition(":")
    if not sep or scheme != "tcp" or not colon or not port.isdigit():
        return
    try:
        socket.create_connection((host.strip("[]"), int(port)), timeout=timeout).close()
    except ConnectionRefusedError:
        raise ClusterError(f"cannot connect to Dask scheduler {address}: connection refused "
                           "(no scheduler listens there: start one, e.g. `dask scheduler`, or check the address)") from None
    except OSError as exc:
        raise ClusterError(f"cannot connect to Dask scheduler {address}: {exc}") from None


def connect(address: str):
    """A client of an existing ``dask.distributed`` scheduler at ``address`` (tcp://host:port)."""
    from distributed import Client

    _probe(address)
    try:
        return Client(address, timeout="20s"), []
    except OSError as exc:
        raise ClusterError(f"cannot connect to Dask scheduler {address}: {exc}") from None


def local_cluster(workers: int, memory_limit: str | None, preload: tuple = (), start: str = "spawn", tuned: bool = True):
    """``workers`` local worker processes of one thread each; ``preload``: modules each worker imports as it starts;
    ``start``: how they start (:func:`.forkserver.ready` gives it: ``forkserver`` once that server is running);
    ``tuned``: spawned workers get :func:`~.workers.worker_env`'s malloc and NumPy settings."""
    import dask
    from distributed import Client, LocalCluster

    with worker_config(tuned), dask.config.set({"distributed.worker.multiprocessing-method": start}):
        cluster = LocalCluster(
            n_workers=workers,
            threads_per_worker=1,
            processes=True,
            dashboard_address=None,
            memory_limit=memory_limit or "auto",
            silence_logs=40,
            preload=[*preload, "lunaralbedo.parallel.workers"],  # its dask_setup: the workers' log filter
            # no dashboard, and its HTTP server (health, metrics) on a free port: Dask's default 8787 warns
            # on stderr when another cluster holds it
            scheduler_kwargs={"dashboard_address": ":0"},
        )
    return Client(cluster), [cluster]


def jobqueue_cluster(kind: str, opts: dict):
    """A dask-jobqueue PBS or Slurm cluster (no job submitted yet).

    ``opts``: queue, cores, memory, walltime, account and any other keyword of
    ``dask_jobqueue.PBSCluster``/``SLURMCluster``.  Each job runs ``cores``
    single-threaded worker processes (tile tasks are single-threaded NumPy).
    """
    try:
        import dask_jobqueue
    except ImportError as exc:  # pragma: no cover - dask-jobqueue is a dependency
        raise LunarAlbedoError(f"--cluster {kind} needs dask-jobqueue: {exc}") from None
    cls = {"pbs": dask_jobqueue.PBSCluster, "slurm": dask_jobqueue.SLURMCluster}[kind]
    kwargs = {k: v for k, v in opts.items() if v is not None and k != "jobs"}
    kwargs.setdefault("cores", 1)
    kwargs.setdefault("memory", "4GB")
    kwargs.setdefault("processes", kwargs["cores"])
    kwargs.setdefault("scheduler_options", {"dashboard_address": None})
    kwargs.setdefault("job_script_prologue", [f"export {k}={v}" for k, v in WORKER_ENV.items()])
    with worker_config():  # the scheduler runs here; the jobs' workers get WORKER_ENV from the prologue
        return cls(**kwargs)


def jobqueue_client(kind: str, opts: dict):
    from distributed import Client

    cluster = jobqueue_cluster(kind, opts)
    cluster.scale(jobs=int(opts.get("jobs") or 1))
    return Client(cluster), [cluster]
