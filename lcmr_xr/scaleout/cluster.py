"""``local_cluster``: a ``distributed.LocalCluster`` whose workers identify as fast as a plain process.

Why: distributed's nanny starts every worker with ``MALLOC_TRIM_THRESHOLD_=65536``
(config ``distributed.nanny.pre-spawn-environ``) so that freed memory goes back to the
system at once.  Setting that variable also switches off glibc's adaptive mmap threshold,
so every temporary above 128 kB (the local-model moment tables and covariances of
``identify`` are several MB each) is mapped and unmapped on every call, page faults
included.  Measured on this 2-core machine (shared, so absolute times are noisy; ratios in
alternating runs): one ``identify`` (N = 3600, window 30, degrees 3-3-3, covariance) took
2.2-2.5x as long with ``MALLOC_TRIM_THRESHOLD_=65536`` as in a plain process, and
0.6-1.1x as long with the setting below, which is what glibc's adaptive thresholds reach on
their own (mmap threshold at most 32 MiB, trim threshold twice that).  A worker then keeps
at most 64 MiB of freed heap before returning it, so its memory as dask sees it stays
close to what it uses.

For workers started otherwise (``dask worker`` on other machines), put the same values in
the dask configuration of the machines that start them::

    distributed:
      nanny:
        pre-spawn-environ:
          MALLOC_TRIM_THRESHOLD_: 67108864
          MALLOC_MMAP_THRESHOLD_: 33554432
"""

from __future__ import annotations

import logging

__all__ = ["WORKER_ENVIRON", "worker_environ", "local_cluster"]

#: Environment the nanny gives each worker process (on top of distributed's defaults).
WORKER_ENVIRON = {"MALLOC_TRIM_THRESHOLD_": str(64 * 2**20), "MALLOC_MMAP_THRESHOLD_": str(32 * 2**20)}


def worker_environ() -> dict:
    """distributed's ``pre-spawn-environ`` with :data:`WORKER_ENVIRON` applied over it.

    Returns
    -------
    dict
        The environment variables a nanny sets before it starts a worker process.

    Examples
    --------
    >>> env = worker_environ()
    >>> env["MALLOC_TRIM_THRESHOLD_"], env["MALLOC_MMAP_THRESHOLD_"]
    ('67108864', '33554432')
    """
    import dask
    import distributed  # noqa: F401 - registers distributed's configuration defaults

    return {**dask.config.get("distributed.nanny.pre-spawn-environ", default={}), **WORKER_ENVIRON}


def local_cluster(n_workers: int = 2, *, threads_per_worker: int = 1, memory_limit="auto",
                  processes: bool = True, dashboard_address: str | None = None,
                  silence_logs: int = logging.WARNING):
    """A ``distributed.LocalCluster`` with the allocator settings of :data:`WORKER_ENVIRON`.

    Parameters
    ----------
    n_workers : int, default 2
        Worker processes.
    threads_per_worker : int, default 1
        Threads per worker (one: ``identify`` keeps a core busy on its own).
    memory_limit : str, int or "auto", default "auto"
        Per-worker memory limit, as for ``LocalCluster`` (e.g. ``"400MB"``).
    processes : bool, default True
        Worker processes (with nannies) rather than threads of this process.
    dashboard_address : str, optional
        E.g. ``":8787"``; default: no dashboard.
    silence_logs : int, default logging.WARNING
        Log level below which cluster messages are dropped.

    Returns
    -------
    distributed.LocalCluster
        Use it as a context manager or close it; connect with ``distributed.Client(cluster)``.

    Examples
    --------
    >>> from distributed import Client
    >>> with local_cluster(1) as cluster, Client(cluster) as client:  # doctest: +SKIP
    ...     client.run(lambda: __import__("os").environ["MALLOC_MMAP_THRESHOLD_"])
    """
    import dask
    from distributed import LocalCluster

    with dask.config.set({"distributed.nanny.pre-spawn-environ": worker_environ()}):
        return LocalCluster(n_workers=n_workers, threads_per_worker=threads_per_worker,
                            memory_limit=memory_limit, processes=processes,
                            dashboard_address=dashboard_address, silence_logs=silence_logs)
