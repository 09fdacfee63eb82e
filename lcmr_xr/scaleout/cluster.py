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

Kept heap versus a memory limit.  A worker of this library holds about 290 MB before its
first task (measured: distributed's worker 135 MB, numba 50 MB, its compiled kernels once
loaded 60 MB, the HDF5 readers 35 MB), and one ``identify`` of an N = 3600 HDD experiment
leaves about 28 MB of freed heap that the next call reuses.  With a small memory limit
(400 MB: distributed pauses a worker at 80 %, 320 MB) that kept heap, and the slow growth
of a fragmented heap over thousands of tasks, paused the workers for good: pausing cannot
free memory that the allocator keeps, nor the libraries' code.  Measured with trimming
alone, the workers still sat at 320 MB after a few tasks, exactly at the pause threshold,
and stalled.  So the workers of :func:`local_cluster` pause at 90 % of their limit
(:data:`PAUSE_FRACTION`; distributed still terminates a worker at 95 %), and each worker
runs :func:`dask_setup` (a distributed preload), which sets that and, when its process
memory is above
:data:`TRIM_FRACTION` of its limit it returns the freed heap to the system (glibc
``malloc_trim``), checked every :data:`TRIM_INTERVAL` seconds.  Workers far below their
limit keep the fast path; a worker near it gives the kept heap back and pays the page
faults of the next call instead.

distributed's statistical profiler is off in these workers (:data:`CLUSTER_CONFIG`).  Why:
a worker samples its threads' stacks every 10 ms and keeps one call tree per second, and
per task prefix, for the last 1 000 seconds (``distributed.admin.low-level-log-length``).
The stacks of a sweep task (xarray, HDF5, numba, dask) are deep and varied, so those trees
were the memory that grew with every experiment and that ``malloc_trim`` could not give
back (live Python objects, not freed heap).  Measured: the one worker of a
``local_cluster(1)`` streaming ``sweep_to_disk`` (window 30, without ``P_std``, 8 per task,
about 14 experiments/s) grew 27 MB per 1 000 experiments (26 MB per minute) with the
profiler and 1.6 MB per 1 000 without it (RSS after ``malloc_trim``, every 100
experiments); a plain process looping the same tasks grew 7.7 MB per 1 000 (noisy; reading
the archive alone 1.3, writing part files alone 0).  Were that growth to continue until the
1 000 s bound it would be about 430 MB (not measured that far): a 400 MB worker reaches its
pause threshold long before.  The dashboard's profile pages are empty for these workers; pass
``local_cluster(..., profile=True)`` for them.

For workers started otherwise (``dask worker`` on other machines), put the same values in
the dask configuration of the machines that start them::

    distributed:
      nanny:
        pre-spawn-environ:
          MALLOC_TRIM_THRESHOLD_: 67108864
          MALLOC_MMAP_THRESHOLD_: 33554432
      admin:
        tick: {interval: 1s}          # CLUSTER_CONFIG: less CPU for an idle cluster
        system-monitor: {interval: 2s}
      worker:
        profile:
          enabled: false  # the profiler's call trees grow ~26 MB per minute of tasks
        preload: [lcmr_xr.scaleout.cluster]  # spill at 85 %, pause at 90 %, trim near the limit
"""

from __future__ import annotations

import contextlib
import logging
import os

__all__ = ["WORKER_ENVIRON", "CLUSTER_CONFIG", "PAUSE_FRACTION", "SPILL_FRACTION", "TRIM_FRACTION", "TRIM_INTERVAL", "worker_environ",
           "local_cluster", "dask_setup", "trim_check"]

#: Environment the nanny gives each worker process (on top of distributed's defaults).
WORKER_ENVIRON = {"MALLOC_TRIM_THRESHOLD_": str(64 * 2**20), "MALLOC_MMAP_THRESHOLD_": str(32 * 2**20)}
#: dask configuration of the scheduler and workers :func:`local_cluster` starts:
#: distributed's statistical profiler off (its call trees were the workers' memory growth;
#: see the module notes), and its event-loop tick measurement every second instead of every
#: 20 ms and its system monitor every 2 s instead of 0.5 s.  Why the last two: they are
#: what an idle cluster spends its CPU on, on the cores the tasks need (measured, a
#: 2-worker ``local_cluster`` doing nothing: 24-27 ms CPU per second per worker and
#: 47-67 ms per second in this process, scheduler included, with distributed's defaults;
#: 10-12 and 20 ms with these, about 4 ms per experiment at 15 experiments/s).  The tick
#: only feeds the "event loop was unresponsive" warning, the monitor the dashboard.
CLUSTER_CONFIG = {"distributed.worker.profile.enabled": False,
                  "distributed.admin.tick.interval": "1s",
                  "distributed.admin.system-monitor.interval": "2s"}
#: The part of :data:`CLUSTER_CONFIG` that ``profile=True`` leaves out.
_PROFILE_OFF = ("distributed.worker.profile.enabled",)
#: Fraction of its memory limit at which a worker pauses (distributed's default 0.8), set
#: by :func:`dask_setup` in every worker it starts: set in the configuration only, a
#: worker that its nanny restarted (after a memory kill, or a ``lifetime``) paused at
#: distributed's default again (measured).
PAUSE_FRACTION = 0.9
#: Fraction of its memory limit above which a worker spills the task results it holds to
#: disk (distributed's default 0.7), set by :func:`dask_setup`.  Why: the ~300 MB of
#: libraries and kernels alone are above 70 % of a 400 MB limit, so a small worker spilled
#: every result it held, from its first task on (measured: a 400 MB worker at 323 MB
#: after its first tasks had spilled 6 keys; spilling cannot free what is not data).
#: Between the trim (:data:`TRIM_FRACTION`) and the pause: the kept heap goes back first.
SPILL_FRACTION = 0.85
#: Fraction of a worker's memory limit above which it returns its freed heap to the system
#: (distributed's default pause threshold).
TRIM_FRACTION = 0.8
#: Seconds between a worker's checks of its memory against :data:`TRIM_FRACTION`.
TRIM_INTERVAL = 0.2
#: Name of the periodic callback :func:`dask_setup` adds to a worker.
_CALLBACK = "lcmr-trim-heap"


def _malloc_trim():
    """glibc's ``malloc_trim`` (None where the C library has none, e.g. macOS, musl)."""
    import ctypes
    import ctypes.util

    try:
        return ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6").malloc_trim
    except (OSError, AttributeError):
        return None


def dask_setup(worker) -> None:
    """distributed preload hook: the worker pauses at :data:`PAUSE_FRACTION` of its memory
    limit, spills at :data:`SPILL_FRACTION`, and above :data:`TRIM_FRACTION` of it returns its freed heap to the system (see
    the module notes).

    The trimming is left out for workers without a memory limit or without glibc's
    ``malloc_trim``.
    Started by :func:`local_cluster`; for other workers pass
    ``--preload lcmr_xr.scaleout.cluster`` to ``dask worker``.

    Parameters
    ----------
    worker : distributed.Worker
        The worker being started.
    """
    from tornado.ioloop import PeriodicCallback

    worker.memory_manager.memory_pause_fraction = PAUSE_FRACTION
    if worker.memory_manager.memory_spill_fraction is not False:  # False: spilling switched off
        worker.memory_manager.memory_spill_fraction = SPILL_FRACTION
    check = trim_check(worker, _malloc_trim())
    if check is None:
        return
    callback = PeriodicCallback(check, TRIM_INTERVAL * 1000)
    worker.periodic_callbacks[_CALLBACK] = callback
    callback.start()


def trim_check(worker, trim):
    """The periodic check of :func:`dask_setup`.

    Parameters
    ----------
    worker : distributed.Worker
        Read: ``memory_manager.memory_limit`` (bytes; 0 or None: no limit) and
        ``monitor.get_process_memory()`` (bytes).
    trim : callable or None
        Called as ``trim(0)`` (glibc ``malloc_trim``: give back every free page).

    Returns
    -------
    callable or None
        A function of no arguments that calls ``trim(0)`` when the worker's process
        memory is above :data:`TRIM_FRACTION` of its limit; None when there is nothing
        to check (no limit, or ``trim`` is None).

    Examples
    --------
    >>> from types import SimpleNamespace
    >>> calls = []
    >>> worker = SimpleNamespace(memory_manager=SimpleNamespace(memory_limit=100),
    ...                          monitor=SimpleNamespace(get_process_memory=lambda: 90))
    >>> trim_check(worker, calls.append)()
    >>> calls
    [0]
    """
    limit = worker.memory_manager.memory_limit
    if not limit or trim is None:
        return None

    def check():
        if worker.monitor.get_process_memory() > TRIM_FRACTION * limit:
            trim(0)

    return check


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
                  silence_logs: int = logging.WARNING, profile: bool = False):
    """A ``distributed.LocalCluster`` with the allocator settings of :data:`WORKER_ENVIRON`,
    the heap trimming of :func:`dask_setup` in every worker, and the settings of
    :data:`CLUSTER_CONFIG` (distributed's statistical profiler off unless ``profile``).

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
    profile : bool, default False
        Keep distributed's statistical profiler in the workers (the dashboard's profile
        pages); its call trees grow a worker's memory by about 26 MB per minute of
        ``identify`` tasks, for up to 1 000 seconds (see the module notes).

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

    preload = list(dask.config.get("distributed.worker.preload", default=[]) or [])
    with dask.config.set({"distributed.nanny.pre-spawn-environ": worker_environ(),
                          "distributed.worker.preload": preload + [__name__],
                          **{key: value for key, value in CLUSTER_CONFIG.items()
                             if not (profile and key in _PROFILE_OFF)}}), \
            _process_environ(WORKER_ENVIRON):
        return LocalCluster(n_workers=n_workers, threads_per_worker=threads_per_worker,
                            memory_limit=memory_limit, processes=processes,
                            dashboard_address=dashboard_address, silence_logs=silence_logs)


@contextlib.contextmanager
def _process_environ(values: dict):
    """``values`` in this process's environment while the nannies are made, then restored.

    Why: a nanny takes a ``pre-spawn-environ`` variable from this process's environment
    when it is set there, ahead of the configuration; and every nanny writes its variables
    into this environment when it spawns its worker.  So after any cluster with
    distributed's defaults (``MALLOC_TRIM_THRESHOLD_=65536``) in the same process, the
    configuration alone was silently ignored (measured: the workers of a later
    ``local_cluster`` got 65536).
    """
    saved = {key: os.environ.get(key) for key in values}
    os.environ.update(values)
    try:
        yield
    finally:
        for key, value in saved.items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value
