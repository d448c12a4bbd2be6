"""The Dask cluster of the commands that run many independent jobs (a dataset's objects, the
bench's experiments): a local cluster of worker processes, or a running one (``--scheduler``).

Dask is imported only when a cluster starts: one object or one experiment at a time loads
none of it. The settings that matter with JAX are in ``docs/design.md`` ("Scaling").
"""

import contextlib
import threading

#: One learning run at a time per process, whatever the worker's thread count: two runs' host
#: callbacks in one process can hold every thread of XLA's CPU pool and deadlock.
ONE_AT_A_TIME = threading.Lock()

#: What the local cluster's workers change from Dask's defaults: no spilling and no pausing
#: (a task's data is small; a process keeps its compiled programs, so its memory may never
#: fall back below a pause threshold); the nanny still restarts a worker that outgrows its
#: memory limit (``terminate``).
LOCAL_CONFIG = {"distributed.worker.memory.target": False,
                "distributed.worker.memory.spill": False,
                "distributed.worker.memory.pause": False}


def add_scheduler_argument(group, what: str) -> None:
    """``--scheduler ADDRESS``: a running Dask cluster instead of a local one."""
    group.add_argument("--scheduler", metavar="ADDRESS",
                       help=f"a running Dask scheduler (tcp://host:8786) instead of a local "
                            f"cluster; its workers must see {what} at the same paths")


@contextlib.contextmanager
def client(scheduler=None, workers=1, threads_per_worker=1):
    """A ``dask.distributed.Client`` of the running cluster at ``scheduler``, else of a
    ``LocalCluster`` of ``workers`` processes (spawned by a nanny each, ``threads_per_worker``
    threads, no dashboard port to clash with another run); closes it (and the local cluster,
    with its workers) on exit."""
    # Dask only for many jobs: a single run loads none of it
    import dask
    from dask.distributed import Client, LocalCluster

    if scheduler:
        cluster, dask_client = None, Client(scheduler)
    else:
        with dask.config.set(LOCAL_CONFIG):  # the nannies hand it to their workers
            cluster = LocalCluster(n_workers=workers, threads_per_worker=threads_per_worker,
                                   processes=True, dashboard_address=None)
        dask_client = Client(cluster)
    try:
        yield dask_client
    finally:
        dask_client.close()
        if cluster is not None:
            cluster.close()
