"""``lcmr-xr sweep``: identify an archive for every combination of settings, in parallel.

    lcmr-xr sweep ARCHIVE_DIR -o RESULT.nc [--window 10 20 30] [--degrees 3-3-3 2-2-2]
                  [--method lrm lpm] [--closed-loop indirect|direct]
                  [--scheduler threads|processes|synchronous|ADDRESS] [--select CHOICE.nc]

``ADDRESS`` (e.g. ``tcp://127.0.0.1:8786``) connects a ``distributed.Client`` to a running
scheduler.  A progress bar is printed to stderr while the sweep computes.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

LOCAL_SCHEDULERS = ("threads", "processes", "synchronous")


def add_sweep_parser(subparsers) -> argparse.ArgumentParser:
    """Add the ``sweep`` sub-command to an ``argparse`` sub-parsers object.

    Parameters
    ----------
    subparsers : argparse._SubParsersAction
        What ``ArgumentParser.add_subparsers()`` returned.

    Returns
    -------
    argparse.ArgumentParser
        The ``sweep`` parser (its ``func`` default is :func:`run_sweep`).

    Examples
    --------
    >>> import argparse
    >>> p = argparse.ArgumentParser(prog="lcmr-xr")
    >>> _ = add_sweep_parser(p.add_subparsers(dest="command"))
    >>> args = p.parse_args(["sweep", "arc", "-o", "r.nc", "--window", "10", "20"])
    >>> args.window, args.degrees, args.method, args.scheduler
    ([10, 20], ['3-3-3'], ['lrm'], 'threads')
    """
    sw = subparsers.add_parser(
        "sweep", help="identify an archive of experiments for every combination of settings",
        description="Identify every experiment of an archive directory for every combination "
                    "of --window, --degrees and --method, in parallel with dask, and write "
                    "one FRF NetCDF file with a dim per setting.")
    sw.add_argument("archive", type=Path, help="archive directory (one experiment .nc per file)")
    sw.add_argument("-o", "--output", type=Path, required=True, help="result NetCDF file to write")
    sw.add_argument("--window", type=int, nargs="+", default=[30], help="window half-widths n (default 30)")
    sw.add_argument("--degrees", nargs="+", default=["3-3-3"], metavar="RN-RM-RD",
                    help="local model degrees, e.g. 3-3-3 2-2-2 (LPM ignores RD; default 3-3-3)")
    sw.add_argument("--method", nargs="+", choices=("lrm", "lpm"), default=["lrm"])
    sw.add_argument("--closed-loop", choices=("indirect", "direct"), default="indirect")
    sw.add_argument("--no-covariance", action="store_true", help="skip P_std (less memory)")
    sw.add_argument("--scheduler", default="threads",
                    help="threads (default), processes, synchronous, or the address of a running "
                         "dask scheduler, e.g. tcp://127.0.0.1:8786")
    sw.add_argument("--select", type=Path, default=None,
                    help="also write the settings with the lowest validation error per experiment")
    sw.set_defaults(func=run_sweep)
    return sw


def _compute(ds, scheduler: str):
    """Compute with a progress bar: dask's for local schedulers, distributed's for a cluster."""
    if scheduler in LOCAL_SCHEDULERS:
        from dask.diagnostics import ProgressBar

        with ProgressBar(out=sys.stderr):
            return ds.compute(scheduler=scheduler)
    if "://" not in scheduler:
        raise ValueError(f"--scheduler {scheduler!r} is neither {'/'.join(LOCAL_SCHEDULERS)} nor an "
                         "address like tcp://127.0.0.1:8786.")
    from distributed import Client, progress

    with Client(scheduler, timeout="20s") as client:
        persisted = client.persist(ds)
        progress(persisted, notebook=False)
        print(file=sys.stderr)
        return persisted.compute()


def _stream(experiments, output, settings, scheduler: str) -> None:
    """``sweep_to_disk`` on the scheduler named on the command line."""
    from lcmr_xr.scaleout.stream import sweep_to_disk

    if scheduler in LOCAL_SCHEDULERS:
        sweep_to_disk(experiments, output, **settings, scheduler=scheduler, overwrite=True)
        return
    if "://" not in scheduler:
        raise ValueError(f"--scheduler {scheduler!r} is neither {'/'.join(LOCAL_SCHEDULERS)} nor an "
                         "address like tcp://127.0.0.1:8786.")
    from distributed import Client

    with Client(scheduler, timeout="20s") as client:
        sweep_to_disk(experiments, output, **settings, client=client, overwrite=True)


def run_sweep(args) -> int:
    """Run ``lcmr-xr sweep`` with parsed arguments; returns the exit status.

    Parameters
    ----------
    args : argparse.Namespace
        From the parser of :func:`add_sweep_parser`.

    Returns
    -------
    int
        0 on success, 2 when the input or settings are wrong (one line on stderr says what;
        nothing is written then).

    Examples
    --------
    >>> import argparse
    >>> args = argparse.Namespace(archive=Path("no-such-dir"), output=Path("r.nc"), window=[30],
    ...     degrees=["3-3-3"], method=["lrm"], closed_loop="indirect", no_covariance=False,
    ...     scheduler="threads", select=None)
    >>> run_sweep(args)
    2
    """
    import numpy as np

    from lcmr_xr.io import open_dataset, save
    from lcmr_xr.scaleout.archive import open_archive
    from lcmr_xr.scaleout.select import select_settings
    from lcmr_xr.scaleout.sweep import sweep

    try:
        for path in (args.output, args.select):
            if path is not None and not (path.parent if str(path.parent) else Path(".")).is_dir():
                raise FileNotFoundError(f"directory of {path} does not exist; create it first.")
        experiments = open_archive(args.archive)
        settings = dict(window=args.window, degrees=args.degrees, method=args.method,
                        closed_loop=args.closed_loop, covariance=not args.no_covariance)
        lazy = sweep(experiments, **settings)  # checks the settings before anything runs
        sizes = {d: lazy.sizes[d] for d in ("method", "degrees", "window", "experiment") if d in lazy.dims}
        print(f"sweeping {sizes} on scheduler {args.scheduler}", file=sys.stderr)
        if "experiment" in lazy.dims:
            # results stream to disk as tasks finish; a rerun after a crash resumes
            _stream(experiments, args.output, settings, args.scheduler)
            result = open_dataset(args.output)
        else:
            result = _compute(lazy, args.scheduler)
            save(result, args.output)
        failed = [str(e) for e in np.unique(result["experiment_error"].values) if str(e)]
        for message in failed:
            print(f"lcmr-xr sweep: flagged {message}", file=sys.stderr)
        flagged = int(result["P_flag"].sum())
        print(f"wrote {args.output}: P {dict(result.P.sizes)}, {flagged} flagged bins")
        if args.select is not None:
            choice = select_settings(result, experiments)
            save(choice, args.select)
            print(f"wrote {args.select}: criterion {choice.attrs['criterion']}")
    except (ValueError, TypeError, FileNotFoundError, OSError) as exc:
        print(f"lcmr-xr sweep: error: {exc}", file=sys.stderr)
        return 2
    return 0
