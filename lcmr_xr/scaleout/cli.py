"""``lcmr-xr sweep``: identify an archive for every combination of settings, in parallel.

    lcmr-xr sweep ARCHIVE -o RESULT.nc [--window 10 20 30] [--degrees 3-3-3 2-2-2 ...]
                  [--method lrm lpm] [--closed-loop indirect|direct] [--denominator ls|iv]
                  [--scheduler threads|processes|synchronous|ADDRESS] [--select CHOICE.nc]
                  [--variables P P_std P_flag ...] [--overwrite]

``ARCHIVE`` is a consolidated archive file or an archive directory
(:func:`lcmr_xr.scaleout.open_archive`).  An archive with an ``experiment`` dim is swept
by :func:`lcmr_xr.scaleout.sweep_to_disk`: each finished task is written at once to a part
file in the hidden directory ``.RESULT.nc.parts/`` next to ``RESULT.nc`` (so never inside
the archive, where ``-o`` may not lie), and rerunning the same command after a crash
computes only the missing parts; the parts are removed once ``RESULT.nc`` is written.
An experiment that cannot be identified is flagged (``experiment_error``, one line per
experiment on stderr), not fatal.  ``--variables`` writes only the named result variables
(and ``experiment_error``): ``P P_std P_flag`` take 90 kB per experiment instead of
1.27 MB, and each task keeps only those in memory.

``ADDRESS`` (e.g. ``tcp://127.0.0.1:8786``) connects a ``distributed.Client`` to a running
scheduler; when nothing, or something that is not a dask scheduler, answers there, the
command fails with a one-line connection error within ``--connect-timeout`` seconds.
Progress is printed to stderr while the sweep computes (plain lines when stderr is not a
terminal).  Outputs are checked before anything is computed: neither ``-o`` nor ``--select``
may lie inside the archive, and existing files are replaced only with ``--overwrite``.
"""

from __future__ import annotations

import argparse
import socket
import sys
from pathlib import Path
from urllib.parse import urlsplit

from lcmr_xr._cli_support import (NETCDF_SUFFIXES, SWEEP_DENOMINATOR_HELP, HelpFormatter, add_overwrite,
                                  check_outputs, error_line, futures_progress, integer_argument,
                                  progress)

from lcmr_xr import conventions as cv
from lcmr_xr.settings import CLOSED_LOOP, DENOMINATOR, METHODS, window_argument

LOCAL_SCHEDULERS = ("threads", "processes", "synchronous")
#: Seconds to wait for a dask scheduler to answer (``--connect-timeout``).
CONNECT_TIMEOUT = 10.0
#: What the ``criterion`` values of ``--select`` mean (help text and output).
CRITERION_HELP = {
    "cross": "held-out experiments: each experiment's estimate predicts the measured lifted "
             "spectra of the other experiments from their excitation; score = median relative "
             "prediction error, lower is better; used with two or more experiments",
    "fpe": "final prediction error of the local model, sigma2 (1 + p / (2n + 1)), relative to "
           "the measured spectra; lower is better; used with one experiment",
}


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
    ([10, 20], None, ['lrm'], 'threads')
    """
    criteria = " ".join(f"'{k}': {v}." for k, v in CRITERION_HELP.items())
    sw = subparsers.add_parser(
        "sweep", help="identify an archive of experiments for every combination of settings",
        formatter_class=HelpFormatter,
        description="Identify every experiment of an archive for every combination "
                    "of --window, --degrees and --method, in parallel with dask, and write "
                    "one FRF NetCDF file with a dim per setting. Finished tasks are kept in "
                    "the hidden directory .OUTPUT.parts/ next to OUTPUT until it is written, "
                    "so the same command resumes after a crash. An experiment that cannot be "
                    "identified is flagged (experiment_error), not fatal. With --select, also "
                    f"write the best settings per experiment by a validation criterion. {criteria}")
    sw.add_argument("archive", type=Path,
                    help="consolidated archive file, or archive directory (one experiment per .nc, .nc4 or .netcdf file)")
    sw.add_argument("-o", "--output", type=Path, required=True,
                    help="result NetCDF file to write (.nc; not inside the archive; its parts "
                         "are kept in .OUTPUT.parts/ next to it while the sweep runs)")
    # the settings' parser: every token reaches the sweep's validator ('auto' is refused there)
    sw.add_argument("--window", type=window_argument, nargs="+", default=[30],
                    help="window half-widths n (fixed: a sweep compares windows)")
    sw.add_argument("--degrees", nargs="+", default=None, metavar="RN-RM-RD",
                    help="local model degrees, one or more RN-RM-RD, e.g. 3-3-3 2-2-2; every one "
                         "is combined with every --method, and LPM needs RD = 0 (default: the "
                         "method's, 3-3-3 for LRM, 3-3-0 for LPM)")
    sw.add_argument("--method", nargs="+", choices=tuple(METHODS), default=["lrm"],
                    help="local rational (lrm) and/or polynomial (lpm) model")
    sw.add_argument("--closed-loop", choices=tuple(CLOSED_LOOP), default="indirect",
                    help="indirect: P = PS S^-1 from the excitation (unbiased); direct: from "
                         "the measured input (biased under feedback)")
    sw.add_argument("--denominator", choices=tuple(DENOMINATOR), default=None,
                    help=SWEEP_DENOMINATOR_HELP)
    sw.add_argument("--variables", nargs="+", default=None, metavar="NAME",
                    help="write only these result variables, e.g. P P_std P_flag "
                         "(experiment_error is always written; default: every variable)")
    sw.add_argument("--no-covariance", action="store_true",
                    help="skip P_std (less memory; default: compute it)")
    sw.add_argument("--scheduler", default="threads",
                    help="threads, processes, synchronous, or the address of a running "
                         "dask scheduler, e.g. tcp://127.0.0.1:8786")
    sw.add_argument("--connect-timeout", type=float, default=CONNECT_TIMEOUT, metavar="SECONDS",
                    help="how long to wait for the scheduler at ADDRESS to answer")
    sw.add_argument("--pool", type=integer_argument, nargs="+", default=None, metavar="K",
                    help="also pool K experiments at a time, one estimate per group of K "
                         "consecutive experiments (result dims pool, pool_group instead of "
                         "experiment), e.g. --pool 1 2 4 8 (default: no pooling)")
    sw.add_argument("--select", type=Path, default=None,
                    help="also write the settings with the lowest validation error per "
                         "experiment (default: no selection); criterion 'cross' with two or more "
                         "experiments, else 'fpe' (see the description above)")
    add_overwrite(sw)
    sw.set_defaults(func=run_sweep)
    return sw


def _check_scheduler(scheduler: str) -> None:
    """Refuse a ``--scheduler`` that is neither a local scheduler nor a ``tcp://host:port``."""
    if scheduler in LOCAL_SCHEDULERS:
        return
    try:
        parts = urlsplit(scheduler)
        ok = parts.scheme in ("tcp", "tls") and bool(parts.hostname) and parts.port is not None
    except ValueError:  # e.g. a port that is not a number
        ok = False
    if not ok:
        raise ValueError(f"--scheduler {scheduler!r} is neither {'/'.join(LOCAL_SCHEDULERS)} nor an "
                         "address like tcp://127.0.0.1:8786.")


def _check_timeout(timeout) -> float:
    """Refuse a ``--connect-timeout`` that is not a positive, finite number of seconds."""
    import math

    if not (isinstance(timeout, (int, float)) and not isinstance(timeout, bool)
            and math.isfinite(timeout) and timeout > 0):
        raise ValueError(f"--connect-timeout must be a positive number of seconds, got {timeout!r}; "
                         f"pass e.g. --connect-timeout {CONNECT_TIMEOUT:g}.")
    return float(timeout)


def _probe(address: str, timeout: float) -> None:
    """Check, with a plain socket, that a dask scheduler answers at ``address`` in time.

    A dask server greets every new connection at once with a framed message whose first
    8 bytes are its length (little-endian).  Nothing listening, no greeting within
    ``timeout``, or a greeting that is not such a length (an HTTP or SSH server) are all
    refused here, before ``distributed`` (which, in the version this was written against,
    waits forever on a silent service and allocates by the junk of a foreign one).
    """
    parts = urlsplit(address)
    try:
        sock = socket.create_connection((parts.hostname, parts.port), timeout=timeout)
    except OSError as err:
        reason = err.strerror or type(err).__name__
        raise ConnectionError(
            f"no dask scheduler answers at {address} ({reason} within {timeout:g} s); start one "
            "(dask scheduler) and pass its address, or use --scheduler threads."
        ) from None
    if parts.scheme != "tcp":  # tls: the greeting comes after the TLS handshake
        sock.close()
        return
    header = b""
    with sock:
        sock.settimeout(timeout)
        try:
            while len(header) < 8:
                chunk = sock.recv(8 - len(header))
                if not chunk:
                    break
                header += chunk
        except OSError:  # socket.timeout included
            pass
    length = int.from_bytes(header, "little") if len(header) == 8 else 0
    if not 0 < length < 1 << 26:
        what = ("did not greet within" if not header else "answered with something else than "
                "the dask protocol within")
        raise ConnectionError(
            f"{address} answers, but not as a dask scheduler (it {what} {timeout:g} s); check "
            "the host and port (a dask scheduler listens on 8786 by default), or use "
            "--scheduler threads."
        )


def connect(address: str, timeout: float = CONNECT_TIMEOUT):
    """A ``distributed.Client`` on the scheduler at ``address``, or a clear error in bounded time.

    Parameters
    ----------
    address : str
        ``tcp://host:port`` (or ``tls://``) of a running dask scheduler.
    timeout : float, default 10
        Seconds to wait for the connection and the scheduler's handshake.

    Returns
    -------
    distributed.Client

    Raises
    ------
    ConnectionError
        Nothing listens at ``address`` (at once), or what answers is not a dask scheduler
        (after at most ``timeout`` seconds).  distributed itself retries a refused
        connection until its timeout and, when a service of another kind answers, may try
        to allocate buffers sized by the junk it receives; both end here in one message.
    """
    import logging

    from distributed import Client

    _check_scheduler(address)
    timeout = _check_timeout(timeout)
    _probe(address, timeout)
    quiet = logging.getLogger("distributed")
    level = quiet.level
    quiet.setLevel(logging.CRITICAL)  # its retries would print tracebacks before our one line
    try:
        return Client(address, timeout=f"{timeout}s")
    except Exception as err:  # noqa: BLE001  (MemoryError, OSError, TimeoutError, protocol errors)
        raise ConnectionError(
            f"{address} answers, but not as a dask scheduler ({type(err).__name__} within "
            f"{timeout:g} s); check the host and port (a dask scheduler listens on 8786 by "
            "default), or use --scheduler threads."
        ) from None
    finally:
        quiet.setLevel(level)


def _announce(message: str | None) -> None:
    if message:
        print(message, file=sys.stderr)


def _compute(ds, scheduler: str, timeout: float = CONNECT_TIMEOUT, announce: str | None = None):
    """Compute with progress on stderr: dask's for local schedulers, distributed's for a
    cluster; ``announce`` is printed once the scheduler is there (after the connection to a
    remote one: a failed connection is not a failed sweep)."""
    if scheduler in LOCAL_SCHEDULERS:
        _announce(announce)
        with progress(sys.stderr):
            return ds.compute(scheduler=scheduler)
    from distributed import futures_of

    with connect(scheduler, timeout) as client:
        _announce(announce)
        persisted = client.persist(ds)
        futures_progress(futures_of(persisted), out=sys.stderr)
        return persisted.compute()


def _stream(experiments, output, settings, args, variables=None, announce: str | None = None) -> None:
    """``sweep_to_disk`` on the scheduler named on the command line (outputs checked
    already); ``announce`` is printed as in :func:`_compute`, after a remote connection."""
    from lcmr_xr.scaleout.stream import sweep_to_disk

    overwrite = getattr(args, "overwrite", False)
    if args.scheduler in LOCAL_SCHEDULERS:
        _announce(announce)
        sweep_to_disk(experiments, output, **settings, scheduler=args.scheduler, overwrite=overwrite,
                      variables=variables)
        return
    with connect(args.scheduler, getattr(args, "connect_timeout", CONNECT_TIMEOUT)) as client:
        _announce(announce)
        sweep_to_disk(experiments, output, **settings, client=client, overwrite=overwrite,
                      variables=variables)


def _variables(lazy, names, select) -> tuple | None:
    """``--variables`` checked against the sweep's result (None: every variable).

    ``--select`` reads the local model's variables of the result; asked together with a
    ``--variables`` that leaves them out, the command is refused before it computes.
    """
    from lcmr_xr.scaleout.stream import _kept_variables

    if names is None:
        return None
    keep = _kept_variables(lazy, names)
    if select is not None:
        needed = [v for v in ("PS", "noise_variance_y", "S", "noise_variance_u")
                  if v in lazy.data_vars and v not in keep]
        if needed:
            raise ValueError(f"--select scores the local model and needs the variables {needed}, "
                             "which --variables leaves out: add them to --variables, or drop "
                             "--select.")
    return keep


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
    ...     scheduler="threads", connect_timeout=10.0, select=None, overwrite=False)
    >>> run_sweep(args)
    2
    """
    import numpy as np

    from lcmr_xr.io import open_dataset, save
    from lcmr_xr.scaleout.archive import open_archive
    from lcmr_xr.scaleout.select import select_settings
    from lcmr_xr.scaleout.stream import check_output_name
    from lcmr_xr.scaleout.sweep import sweep, sweep_settings
    from lcmr_xr.settings import degrees_arguments

    try:
        settings = dict(window=args.window, method=args.method, closed_loop=args.closed_loop,
                        covariance=not args.no_covariance,
                        denominator=getattr(args, "denominator", None),
                        degrees=None if args.degrees is None else degrees_arguments(args.degrees))
        sweep_settings(**settings)  # before the archive is opened
        pool = getattr(args, "pool", None)
        if pool is not None and args.select is not None:
            raise ValueError("--select compares settings per experiment; with --pool the "
                             "estimates are per group of experiments: drop one of them.")
        _check_scheduler(args.scheduler)
        _check_timeout(getattr(args, "connect_timeout", CONNECT_TIMEOUT))  # before any output
        check_output_name(args.output, "-o")  # names the parts a sweep left under a refused name
        check_outputs({"-o": (args.output, NETCDF_SUFFIXES), "--select": (args.select, NETCDF_SUFFIXES)},
                      inputs=[args.archive], overwrite=getattr(args, "overwrite", False))
        experiments = open_archive(args.archive)
        lazy = sweep(experiments, **settings, pool=pool)
        keep = _variables(lazy, getattr(args, "variables", None), args.select)
        sizes = {d: lazy.sizes[d] for d in ("method", "degrees", "window", "experiment", "pool",
                                            "pool_group") if d in lazy.dims}
        # said once the scheduler answers (after connecting to a remote one): a connection
        # that fails is then one error line, not a sweep that started and failed
        announce = f"sweeping {sizes} on scheduler {args.scheduler}"
        if "experiment" in lazy.dims:
            # results stream to disk as tasks finish (parts next to the output, never in the
            # archive: the output was checked to lie outside it); a rerun after a crash resumes
            _stream(experiments, args.output, settings, args, variables=keep, announce=announce)
            result = open_dataset(args.output)
        else:
            lazy = lazy if keep is None else lazy[list(keep)]
            result = _compute(lazy, args.scheduler, getattr(args, "connect_timeout", CONNECT_TIMEOUT),
                              announce=announce)
            save(result, args.output)
        failed = [str(e) for e in np.unique(result[cv.EXPERIMENT_ERROR].values) if str(e)] \
            if cv.EXPERIMENT_ERROR in result else []  # (pooled: no per-experiment results)
        for message in failed:
            print(f"lcmr-xr sweep: flagged {message}", file=sys.stderr)
        written = f"P {dict(result.P.sizes)}" if "P" in result else f"variables {sorted(result.data_vars)}"
        flagged = f", {int(result['P_flag'].sum())} flagged bins" if "P_flag" in result else ""
        print(f"wrote {args.output}: {written}{flagged}")
        if args.select is not None:
            choice = select_settings(result, experiments)
            save(choice, args.select)
            criterion = choice.attrs["criterion"]
            print(f"wrote {args.select}: criterion {criterion} "
                  f"({CRITERION_HELP.get(criterion, 'see lcmr_xr.scaleout.select_settings')})")
    except (ValueError, TypeError, FileNotFoundError, OSError) as exc:
        print(error_line("sweep", exc), file=sys.stderr)
        return 2
    return 0
