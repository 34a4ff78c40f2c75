"""Where tasks run: in-process, on local workers, an existing scheduler, PBS_NODEFILE nodes or PBS/Slurm jobs.

Every executor offers ``map(fn, items, desc)`` that returns results **in the order
of the items**, whatever order workers finish in (the solver reduces them in
that order, so results are identical for any number of workers), and
``compute(tasks)`` for a graph of ``dask.delayed`` tasks (the export's).

``map(..., home=label)`` keeps an item on one worker across maps: ``place(label, costs)``
sets each item's worker so that they share the work evenly, else the first map with a
label notes which worker ran each item; later maps with that label ask for the same
worker (a loose restriction: an idle worker may still take the task).  The solver places
its tiles by their observation counts once they are prepared, so a tile's iterations run
where its cached blocks are held in memory (:data:`lunaralbedo.engine.tilework.STACKS` is
per process) and its finalise task frees them there.
"""
from __future__ import annotations

from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any, Callable, Iterable

from tqdm.auto import tqdm

from ..errors import ClusterError, LunarAlbedoError, typed_error
from . import clusters, forkserver
from .nodefile import nodefile_client, pbs_nodes
from ..runtime import Runtime
from .workers import WorkerLogFilter, available_cpus, tune_malloc, tune_numpy


#: Tasks per worker of a map whose items have homes (see :meth:`DaskExecutor._submit`).
BATCHES_PER_WORKER = 4


class SerialExecutor:
    """Runs tasks one after another in this process (1 worker; no Dask overhead).

    ``cpus_per_task``: the CPUs a task may keep busy with threads of its own (GDAL's
    compression of the tiles it writes): all of this process's, since nothing else runs.
    """

    workers = 1
    description = "in-process (1 worker)"
    #: Tasks run in this process: what they leave in its memory (e.g. the cache writer's queue) is the caller's.
    in_process = True

    @property
    def cpus_per_task(self) -> int:
        return available_cpus()

    def __init__(self, progress: bool = False):
        self.progress = progress

    def map(self, fn: Callable, items: Iterable, desc: str = "", shared: tuple = (), home: str | None = None,
            meanwhile: bool = False, threads: int = 1, **kwargs: Any) -> list:
        """``fn(item, **kwargs)`` for every item, in order.  ``threads`` > 1: tasks that release the GIL
        (numba ``nogil`` kernels) may run that many at once on this process's threads (executors whose
        workers have one CPU each ignore it); the results come back in the order of the items all the same."""
        items = list(items)  # one process: every item is at home
        if threads > 1 and len(items) > 1:
            return _on_threads(fn, items, min(threads, len(items)), desc, self.progress, kwargs)
        return [fn(x, **kwargs) for x in tqdm(items, desc=desc, disable=not self.progress, leave=False)]

    def place(self, label: str, costs: dict) -> None:
        """Homes for the items of ``costs`` in later maps labelled ``label`` (one process: nothing to place)."""

    def compute(self, tasks: list) -> list:
        """Compute a list of ``dask.delayed`` objects, in order."""
        import dask

        return list(dask.compute(*tasks, scheduler="synchronous")) if tasks else []

    def close(self) -> None:
        pass


def _on_threads(fn: Callable, items: list, threads: int, desc: str, progress: bool, kwargs: dict) -> list:
    """``fn(item, **kwargs)`` for every item on ``threads`` threads of this process, results in the order of the items.

    The first failure (in the items' order) is raised once the tasks already running have ended;
    the items not started yet are dropped, as a cluster's pending tasks are.
    """
    with ThreadPoolExecutor(threads) as pool:
        futures = [pool.submit(fn, x, **kwargs) for x in items]
        try:
            return [f.result() for f in tqdm(futures, desc=desc, disable=not progress, leave=False)]
        except BaseException:
            for f in futures:
                f.cancel()
            raise


class LocalPoolExecutor(SerialExecutor):
    """Runs tasks on ``workers`` threads of this process (GIL-releasing work: GDAL reads and writes)."""

    cpus_per_task = 1  # the pool's threads keep the CPUs busy

    def __init__(self, workers: int, progress: bool = False):
        super().__init__(progress)
        self.workers = workers
        self.description = f"thread pool ({workers} threads)"

    def map(self, fn: Callable, items: Iterable, desc: str = "", shared: tuple = (), home: str | None = None,
            meanwhile: bool = False, threads: int = 1, **kwargs: Any) -> list:
        return _on_threads(fn, list(items), self.workers, desc, self.progress, kwargs)

    def compute(self, tasks: list) -> list:
        import dask

        return list(dask.compute(*tasks, scheduler="threads", num_workers=self.workers)) if tasks else []


class DaskExecutor:
    """Runs tasks on a ``distributed.Client`` (local processes, a remote scheduler, or a job-queue cluster).

    ``client`` may also be a :class:`concurrent.futures.Future` of ``(client, owned)``: a cluster
    still starting in a background thread (:func:`make_executor` with ``background=True``).
    Until it is up, maps with ``meanwhile=True`` run on ``workers`` threads of this process;
    anything else waits for it (and raises its :class:`ClusterError` if it failed to start).
    ``cpus_per_task`` is 1: a worker's task thread is its share of the machine.
    """

    cpus_per_task = 1
    in_process = False  # tasks run in the workers' processes

    def __init__(self, client, description: str, progress: bool = False, owned=(), own_client: bool = True,
                 workers: int | None = None):
        self._client = client
        self._own_client = own_client
        self.description = description
        self.progress = progress
        self._owned = owned
        self._scattered: dict[int, tuple[Any, Any]] = {}
        self._homes: dict[str, dict] = {}  # label -> {item: worker address}
        self.workers = workers or max(1, len((self.client.scheduler_info() or {}).get("workers", {})))

    @property
    def client(self):
        """The ``distributed.Client`` (waits for a cluster starting in the background)."""
        if isinstance(self._client, Future):
            self._client, owned = self._client.result()
            self._owned = (*self._owned, *owned)
        return self._client

    def _starting(self) -> bool:
        return isinstance(self._client, Future) and not self._client.done()

    def map(self, fn: Callable, items: Iterable, desc: str = "", shared: tuple = (), home: str | None = None,
            meanwhile: bool = False, threads: int = 1, **kwargs: Any) -> list:
        """Run ``fn(item, **kwargs)`` for every item; ``shared`` names large kwargs sent to each worker once;
        ``home``: keep each (hashable) item on the worker that ran it in the first map with this label;
        ``meanwhile``: run in this process's threads if the workers are still starting (GDAL reads);
        ``threads``: ignored (a worker's task thread is its share of the machine)."""
        from distributed import as_completed

        items = list(items)
        if not items:
            return []
        if meanwhile and self._starting():
            return LocalPoolExecutor(self.workers, self.progress).map(fn, items, desc, **kwargs)
        args = {k: (self._scatter(v) if k in shared else v) for k, v in kwargs.items()}
        homes = self._homes.get(home) if home else None
        futures, spans = self._submit(fn, items, args, homes)
        try:
            if self.progress:
                size = {f.key: len(at) for f, at in zip(futures, spans)}
                with tqdm(total=len(items), desc=desc, leave=False) as bar:
                    for fut in as_completed(futures):
                        if fut.status == "error":
                            raise _first_error(fut)
                        bar.update(size[fut.key])
            parts = self.client.gather(futures)
            if home and home not in self._homes:
                self._homes[home] = self._placement(items, futures)
        except BaseException as exc:
            self.client.cancel(futures)  # the first real error is raised; the remaining tasks stop
            typed = _typed(exc)
            if typed is exc:
                raise
            raise typed from exc
        if homes is None:
            return parts
        results: list = [None] * len(items)
        for at, part in zip(spans, parts):
            for i, r in zip(at, part):
                results[i] = r
        return results

    def _submit(self, fn: Callable, items: list, args: dict, homes: dict | None) -> tuple[list, list]:
        """Futures and the item positions each one computes.

        Without ``homes``: one task ``run_task(fn, item, **args)`` per item, in item order, in one
        graph update (as ``gather`` then raises the first task error as it comes: 1.7 ms of this
        process's CPU per task, against 4.5 ms for one ``submit`` per item followed by
        ``as_completed``, docs/performance-history.md section 0b; that loop only feeds the bar).  With
        ``homes``: each worker's items in :data:`BATCHES_PER_WORKER` tasks of :func:`run_batch`
        asked of it.  The solver's iterations are maps of ~10 ms tile tasks, whose Dask costs (this
        process's scheduler, the workers' bookkeeping) took 5-6 s of a 2-worker run's CPU on
        2 cores; the homes already share the work out evenly (:meth:`place`), and an idle worker
        may still take a whole batch (docs/performance-history.md, section 0e).
        """
        if homes is None:
            return self.client.map(run_task, [fn] * len(items), items, pure=False, **args), [[i] for i in range(len(items))]
        by_worker: dict = {}
        for i, item in enumerate(items):
            by_worker.setdefault(homes.get(item), []).append(i)
        futures, spans = [], []
        for worker, at in by_worker.items():
            where = {} if worker is None else {"workers": [worker], "allow_other_workers": True}
            n = min(BATCHES_PER_WORKER, len(at))
            for b in range(n):
                batch = at[b * len(at) // n:(b + 1) * len(at) // n]
                futures.append(self.client.submit(run_batch, fn, [items[i] for i in batch], pure=False, **where, **args))
                spans.append(batch)
        return futures, spans

    def place(self, label: str, costs: dict) -> None:
        """Homes for the maps labelled ``label``, balanced by ``costs`` ({item: work, any unit}).

        Longest processing time first: items by decreasing cost (ties in item order), each to
        the worker with the least work so far (ties: the first address).  Every worker then gets
        about the same share of each later map, whose tasks all end near the same time (a map is
        a barrier: the solver reduces its results before the next), where the homes of a first
        map follow whichever worker happened to be free.  Deterministic for given workers.
        """
        addresses = sorted((self.client.scheduler_info() or {}).get("workers", {}))
        if not addresses:
            return
        load = dict.fromkeys(addresses, 0.0)
        homes = {}
        for item, cost in sorted(costs.items(), key=lambda kv: -kv[1]):  # stable: ties keep item order
            worker = min(addresses, key=load.__getitem__)
            homes[item] = worker
            load[worker] += cost
        self._homes[label] = homes

    def _placement(self, items: list, futures: list) -> dict:
        """``{item: address of the worker holding its result}`` (the worker that ran it)."""
        held = self.client.who_has(futures)
        return {item: held[f.key][0] for item, f in zip(items, futures) if held.get(f.key)}

    def compute(self, tasks: list) -> list:
        """Compute a list of ``dask.delayed`` objects on the cluster, in order."""
        return list(self.client.gather(self.client.compute(tasks))) if tasks else []

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
        try:
            client = self.client  # a cluster still starting is waited for, then closed
        except LunarAlbedoError:  # it failed to start: nothing to close
            return
        for obj in ((client,) if self._own_client else ()) + tuple(self._owned):
            try:
                obj.close()
            except Exception:  # noqa: BLE001 - closing is best effort
                pass


def _identity(value):
    return value


def run_batch(fn: Callable, items: list, **kwargs) -> list:
    """``[run_task(fn, item, **kwargs) for item in items]`` on a worker (one Dask task)."""
    return [run_task(fn, item, **kwargs) for item in items]


def run_task(fn: Callable, item, **kwargs):
    """Run one task on a worker; a failure comes back as its typed error, without its chain.

    Dask pickles a task's exception with its ``__context__`` chain, and GDAL's exception
    classes do not survive that: the client would get a bare ``Exception(repr)``.  The worker's
    own log of a typed error (:class:`~.workers.WorkerLogFilter`) is left out: the command reports it.
    """
    try:
        return fn(item, **kwargs)
    except Exception as exc:  # noqa: BLE001 - re-raised below
        error = typed_error(exc) or exc
    if isinstance(error, LunarAlbedoError):
        error.__cause__ = error.__context__ = None
        WorkerLogFilter.install()
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
    client=None,
    local: str = "processes",
    background: bool = False,
    preload: tuple = (),
    runtime: Runtime | None = None,
):
    """Choose an executor; the same rules for ``ingest``, ``solve`` and ``export-kml``.

    * ``client``: a ``distributed.Client`` the caller owns (Python API; not closed here);
    * ``scheduler="tcp://host:port"``: connect to an existing ``dask.distributed`` scheduler;
    * ``cluster="pbs"|"slurm"``: start workers as batch jobs with dask-jobqueue
      (``cluster_options``: queue, cores, memory, walltime, jobs, account, ...);
    * ``runtime.nodefile`` given (a PBS job's ``$PBS_NODEFILE``, as the legacy program used it):
      ``workers`` processes on every node it lists (see :mod:`.nodefile`);
    * otherwise ``workers`` local workers (1: in-process, no Dask): processes of a
      local Dask cluster, or with ``local="threads"`` a thread pool of this process
      (for GDAL-bound tasks that release the GIL, such as the export's).

    ``background=True`` starts a local cluster in a background thread and returns at once
    (:class:`DaskExecutor` then waits for it where it must); ``preload``: modules its
    workers import as they start, so that the first tasks do not wait for the imports.
    The solver overlaps the ~1-2 s of that start with building its scene (docs/scaling.md).
    Local workers are forked from a server that has imported ``preload`` once (:mod:`.forkserver`;
    ``runtime.worker_start="spawn"``: each a fresh interpreter, Dask's default).  ``runtime``
    (:class:`lunaralbedo.runtime.Runtime`) also says whether workers and this process are tuned; by
    default this process is left as it is.
    """
    runtime = runtime or Runtime()
    if client is not None:
        return DaskExecutor(client, "Dask client", progress, own_client=False)
    if scheduler:
        client, owned = _starting(f"connection to Dask scheduler {scheduler}", clusters.connect, scheduler)
        return DaskExecutor(client, f"scheduler {scheduler}", progress, owned=owned)
    if cluster:
        client, owned = _starting(f"{cluster} cluster", clusters.jobqueue_client, cluster, dict(cluster_options or {}))
        return DaskExecutor(client, f"{cluster} cluster", progress, owned=owned)
    hosts = pbs_nodes(runtime.nodefile)
    if hosts:
        client, owned = nodefile_client(hosts, max(1, workers), remote_shell=runtime.remote_shell,
                                        tuned=runtime.tune_workers)
        return DaskExecutor(client, f"PBS_NODEFILE ({len(hosts)} nodes x {max(1, workers)} processes)", progress, owned=owned)
    if runtime.tune_process:  # for tasks run in this process (one worker, threads); workers are tuned apart
        tune_malloc()
        tune_numpy()
    if workers <= 1:
        return SerialExecutor(progress)
    if local == "processes":
        if runtime.wide_vectors:  # the workers compile for this process's vector width (and its cache entries)
            preload = (forkserver.VECTORS_SETUP, *preload)
        what, description = f"local cluster of {workers} processes", f"local cluster ({workers} processes)"
        start = _starting("server of local workers", forkserver.ready, preload, runtime.worker_start, runtime.tune_workers)
        if background:
            pool = ThreadPoolExecutor(1, thread_name_prefix="lunaralbedo-cluster-start")
            pending = pool.submit(_starting, what, clusters.local_cluster, workers, memory_limit, preload, start,
                                  runtime.tune_workers)
            pool.shutdown(wait=False)  # the start goes on; its thread ends with it
            return DaskExecutor(pending, description, progress, workers=workers)
        client, owned = _starting(what, clusters.local_cluster, workers, memory_limit, preload, start, runtime.tune_workers)
        return DaskExecutor(client, description, progress, owned=owned)
    if local == "threads":
        return LocalPoolExecutor(workers, progress)
    raise ValueError(f"local workers must be 'processes' or 'threads', got {local!r}")
