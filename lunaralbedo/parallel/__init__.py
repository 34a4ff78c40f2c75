"""Parallel execution shared by ingest, solve and export: executors, clusters, PBS/Slurm, PBS_NODEFILE.

``--workers N`` and ``--scheduler ADDRESS`` mean the same in every command: N
workers on this machine, or the workers of an existing Dask scheduler.  See
:func:`make_executor`.
"""
from .clusters import jobqueue_cluster
from .executor import DaskExecutor, LocalPoolExecutor, SerialExecutor, make_executor
from .nodefile import pbs_nodes
from .workers import WORKER_ENV, local_workers

__all__ = ["DaskExecutor", "LocalPoolExecutor", "SerialExecutor", "WORKER_ENV", "jobqueue_cluster", "local_workers",
           "make_executor", "pbs_nodes"]
