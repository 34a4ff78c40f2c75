"""Where tile tasks run: in-process, on a local Dask cluster, an existing scheduler, or PBS/Slurm.

Every executor offers ``map(fn, items, desc)`` that returns results **in the order
of the items**, whatever order workers finish in; the solver reduces them in
that order, so results are identical for any number of workers.
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Callable, Iterable

from tqdm.auto import tqdm

from ..errors import ClusterError, LunarAlbedoError, typed_error


class SerialExecutor:
    """Runs tasks one after another in this process (1 worker; no Dask overhead)."""

    workers = 1
    description = "in-process (1 worker)"

    def __init__(self, progress: bool = False):
        self.progress = progress

    def map(self, fn: Callable, items: Iterable, desc: str = "", shared: tuple = (), **kwargs: Any) -> list:
        items = list(items)
        return [fn(x, **kwargs) for x in tqdm(items, desc=desc, disable=not self.progress, leave=False)]

    def close(self) -> None:
        pass


class DaskExecutor:
    """Runs tasks on a ``distributed.Client`` (local processes, a remote scheduler, or a job-queue cluster)."""

    def __init__(self, client, description: str, progress: bool = False, owned=()):
        self.client = client
        self.description = description
        self.progress = progress
        self._owned = owned
        self._scattered: dict[int, tuple[Any, Any]] = {}
        info = client.scheduler_info() or {}
        self.workers = max(1, len(info.get("workers", {})))

    def map(self, fn: Callable, items: Iterable, desc: str = "", shared: tuple = (), **kwargs: Any) -> list:
        """Run ``fn(item, **kwargs)`` for every item; ``shared`` names large kwargs sent to each worker once."""
        from distributed import as_completed

        items = list(items)
        if not items:
            return []
        args = {k: (self._scatter(v) if k in shared else v) for k, v in kwargs.items()}
        futures = [self.client.submit(run_task, fn, x, pure=False, **args) for x in items]
        try:
            with tqdm(total=len(futures), desc=desc, disable=not self.progress, leave=False) as bar:
                for fut in as_completed(futures):
                    if fut.status == "error":
                        raise _first_error(fut)
                    bar.update(1)
            return self.client.gather(futures)
        except BaseException as exc:
            self.client.cancel(futures)  # the first real error is raised; the remaining tasks stop
            typed = _typed(exc)
            if typed is exc:
                raise
            raise typed from exc

    def _scatter(self, value):
        """Send a large shared argument (the scene) to the workers once and keep the future alive.

        It is a task's result rather than scattered data, so the scheduler can recompute it
        when the worker holding it dies (scattered data would be lost with the worker, and
        every task needing it cancelled).
        """
        if id(value) not in self._scattered:
            self._scattered[id(value)] = (value, self.client.submit(_identity, value, pure=False))
        return self._scattered[id(value)][1]

    def close(self) -> None:
        self._scattered.clear()
        for obj in (self.client, *self._owned):
            try:
                obj.close()
            except Exception:  # noqa: BLE001 - closing is best effort
                pass


def _identity(value):
    return value


def run_task(fn: Callable, item, **kwargs):
    """Run one task on a worker; a failure comes back as its typed error, without its chain.

    Dask pickles a task's exception with its ``__context__`` chain, and GDAL's exception
    classes do not survive that: the client would get a bare ``Exception(repr)``.
    """
    try:
        return fn(item, **kwargs)
    except Exception as exc:  # noqa: BLE001 - re-raised below
        error = typed_error(exc) or exc
    if isinstance(error, LunarAlbedoError):
        error.__cause__ = error.__context__ = None
    raise error


def _first_error(failed):
    """The exception of the task that failed (asked for before anything is cancelled)."""
    try:
        return failed.exception()
    except BaseException as exc:  # noqa: BLE001 - the scheduler lost the task itself
        return exc


def _typed(exc: BaseException) -> BaseException:
    """``exc`` as a typed error when it stands for one (raster failure, lost worker, full disk)."""
    return typed_error(exc) or exc


#: Environment of worker processes.  Dask's nanny sets MALLOC_TRIM_THRESHOLD_, which
#: freezes glibc's mmap threshold at 128 KiB: every multi-megabyte NumPy temporary is
#: then a fresh mmap with page faults (measured 1.5-2x slower tile tasks).  A 64 MiB
#: threshold lets temporaries reuse heap memory, as in a plain Python process.
WORKER_ENV = {"MALLOC_MMAP_THRESHOLD_": 64 * 2**20}


def _worker_config():
    import dask

    return dask.config.set({f"distributed.nanny.pre-spawn-environ.{k}": v for k, v in WORKER_ENV.items()})


def _local_cluster(workers: int, memory_limit: str | None):
    from distributed import Client, LocalCluster

    with _worker_config():
        cluster = LocalCluster(
            n_workers=workers,
            threads_per_worker=1,
            processes=True,
            dashboard_address=None,
            memory_limit=memory_limit or "auto",
            silence_logs=40,
        )
    return Client(cluster), cluster


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
    return cls(**kwargs)


def _jobqueue_client(kind: str, opts: dict):
    from distributed import Client

    cluster = jobqueue_cluster(kind, opts)
    cluster.scale(jobs=int(opts.get("jobs") or 1))
    return Client(cluster), cluster


def pbs_nodes(nodefile: str | os.PathLike | None = None) -> list[str]:
    """Unique host names of ``$PBS_NODEFILE`` (one per line, as PBS writes it), in order."""
    path = nodefile or os.environ.get("PBS_NODEFILE")
    if not path:
        return []
    try:
        lines = Path(path).read_text().split()
    except OSError as exc:
        raise LunarAlbedoError(f"{path}: cannot read PBS_NODEFILE: {exc}") from None
    return list(dict.fromkeys(h.strip() for h in lines if h.strip()))


def _starting(what: str, start: Callable, *args):
    """``start(*args)``; a failure to start a cluster is a :class:`ClusterError` (exit status 3)."""
    try:
        return start(*args)
    except LunarAlbedoError:
        raise
    except Exception as exc:  # noqa: BLE001 - Dask raises many kinds (TimeoutError, OSError, RuntimeError)
        raise ClusterError(f"cannot start the {what}: {type(exc).__name__}: {exc}") from exc


def make_executor(
    workers: int = 1,
    scheduler: str | None = None,
    cluster: str | None = None,
    cluster_options: dict | None = None,
    progress: bool = False,
    memory_limit: str | None = None,
):
    """Choose an executor.

    * ``scheduler="tcp://host:port"``: connect to an existing ``dask.distributed`` scheduler;
    * ``cluster="pbs"|"slurm"``: start workers as batch jobs with dask-jobqueue
      (``cluster_options``: queue, cores, memory, walltime, jobs, account, ...);
    * ``$PBS_NODEFILE`` set (inside a PBS job, as the legacy program used it):
      ``workers`` processes on every node it lists (see :mod:`.nodefile`);
    * otherwise ``workers`` local worker processes (1: in-process, no Dask).
    """
    if scheduler:
        from distributed import Client

        try:
            client = Client(scheduler, timeout="20s")
        except OSError as exc:
            raise ClusterError(f"cannot connect to Dask scheduler {scheduler}: {exc}") from None
        return DaskExecutor(client, f"scheduler {scheduler}", progress)
    if cluster:
        client, clus = _starting(f"{cluster} cluster", _jobqueue_client, cluster, dict(cluster_options or {}))
        return DaskExecutor(client, f"{cluster} cluster", progress, owned=(clus,))
    hosts = pbs_nodes()
    if hosts:
        from .nodefile import nodefile_client

        client, owned = nodefile_client(hosts, max(1, workers))
        return DaskExecutor(client, f"PBS_NODEFILE ({len(hosts)} nodes x {max(1, workers)} processes)", progress, owned=owned)
    if workers <= 1:
        return SerialExecutor(progress)
    client, clus = _starting(f"local cluster of {workers} processes", _local_cluster, workers, memory_limit)
    return DaskExecutor(client, f"local cluster ({workers} processes)", progress, owned=(clus,))
