"""What every ``lcmr-xr`` sub-command shares: help with defaults, output guards, progress.

- :class:`HelpFormatter` appends ``(default: ...)`` to every option that has a default,
  so ``lcmr-xr simulate --help`` shows what an omitted option means.
- :func:`add_overwrite` and :func:`check_outputs` (from :mod:`lcmr_xr.io._guards`): all
  outputs are checked, before any computation, against the inputs and existing files.
- :func:`progress` shows dask progress on stderr: dask's animated bar on a terminal, one
  plain line per 10 % otherwise (logs and CI capture no carriage-return animation).
- :func:`heartbeat` shows that one long, indivisible call is still running (elapsed
  seconds), for work that has no steps to count, such as an eager ``identify``.
"""

from __future__ import annotations

import argparse
import contextlib
import sys
import threading
import time

# re-exported for the CLIs; the NetCDF endings are lcmr_xr.save's, one list
from lcmr_xr.io._guards import MAT_SUFFIX, NETCDF_SUFFIXES, check_outputs  # noqa: F401
#: File name endings of figures (``lcmr_xr.plot.save_figure`` writes PNG).
FIGURE_SUFFIXES = (".png",)


class HelpFormatter(argparse.HelpFormatter):
    """Append ``(default: X)`` to the help of every option that has a meaningful default."""

    def _get_help_string(self, action):
        text = action.help or ""
        if "default" in text or not action.option_strings:
            return text
        default = action.default
        if default is None or default is False or default is argparse.SUPPRESS:
            return text
        if isinstance(default, (list, tuple)):
            default = " ".join(str(d) for d in default)
        return f"{text} (default: {default})"


def error_line(command: str, exc: BaseException) -> str:
    """The one line a refused command prints: ``lcmr-xr CMD: error: MESSAGE`` (lines joined)."""
    message = " ".join(line.strip() for line in str(exc).splitlines() if line.strip())
    return f"lcmr-xr {command}: error: {message}"


def integer_argument(text: str) -> int:
    """A command line's whole-number token (``--samples``, ``--seed``, ``--case``,
    ``--pool``) by the library's one integer rule (:func:`lcmr_xr.settings.as_integer`):
    ``400`` and ``400.0`` are 400, ``400.5`` is refused (never rounded), as in Python
    and as ``--window`` does.  argparse puts the option's name before the message.

    Examples
    --------
    >>> integer_argument("400"), integer_argument("400.0")
    (400, 400)
    """
    from lcmr_xr.settings import as_integer

    text = str(text).strip()
    try:
        return int(text)
    except ValueError:
        pass
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number; give one in "
                                         "digits") from None
    try:
        return as_integer(value, "value")
    except ValueError:
        pass
    nearest = f"{int(value // 1)} or another" if value == value and abs(value) != float("inf") else "a"
    raise argparse.ArgumentTypeError(f"{text!r} is not a whole number (it is not rounded); "
                                     f"give {nearest} whole number")


def add_overwrite(parser: argparse.ArgumentParser) -> None:
    """The ``--overwrite`` flag: replace existing output files (never an input)."""
    parser.add_argument("--overwrite", action="store_true",
                        help="replace existing output files (default: refuse them); an input "
                             "is never overwritten")


def _is_terminal(stream) -> bool:
    try:
        return stream.isatty()
    except (AttributeError, ValueError):
        return False


class LineProgressBar:
    """dask progress as plain lines, ``NN% Completed | done/total tasks | T s``, every 10 %."""

    def __init__(self, out=None, step: int = 10, label: str = ""):
        self._out = out if out is not None else sys.stderr
        self._step = step
        self._label = label

    def _line(self, percent: int, done: int, total: int) -> None:
        elapsed = time.perf_counter() - self._start
        self._out.write(f"{self._label}{percent:3d}% Completed | {done}/{total} tasks | "
                        f"{elapsed:.1f} s\n")
        self._out.flush()

    def __enter__(self):
        from dask.callbacks import Callback

        bar = self

        class _Callback(Callback):
            def _start_state(self, dsk, state):
                bar._start = time.perf_counter()
                bar._next = 0
                bar._total = sum(len(state[k]) for k in ("ready", "waiting", "running")) + len(state["finished"])
                bar._done = len(state["finished"])

            def _posttask(self, key, result, dsk, state, worker_id):
                bar._done += 1
                bar._report(False)

            def _finish(self, dsk, state, errored):
                if not errored:
                    bar._report(True)

        self._start = time.perf_counter()
        self._callback = _Callback()
        self._callback.__enter__()
        return self

    def _report(self, final: bool) -> None:
        total = max(self._total, 1)
        percent = 100 if final else min(int(100 * self._done / total), 99)
        if final or percent >= self._next:
            self._line(percent, total if final else self._done, total)
            self._next = (percent // self._step + 1) * self._step

    def __exit__(self, *exc):
        self._callback.__exit__(*exc)
        return False


def progress(out=None):
    """A context manager that shows the progress of dask computations on ``out`` (stderr)."""
    out = out if out is not None else sys.stderr
    if _is_terminal(out):
        from dask.diagnostics import ProgressBar

        return ProgressBar(out=out)
    return LineProgressBar(out=out)


def futures_progress(futures, out=None, step: int = 10) -> None:
    """Wait for distributed futures, showing progress (lines when ``out`` is no terminal)."""
    out = out if out is not None else sys.stderr
    if _is_terminal(out):
        from distributed import progress as distributed_progress

        distributed_progress(futures, notebook=False)
        print(file=out)
        return
    from distributed import as_completed

    total, done, next_percent, start = len(futures), 0, 0, time.perf_counter()
    for _ in as_completed(futures):
        done += 1
        percent = int(100 * done / max(total, 1))
        if percent >= next_percent or done == total:
            out.write(f"{percent:3d}% Completed | {done}/{total} tasks | "
                      f"{time.perf_counter() - start:.1f} s\n")
            out.flush()
            next_percent = (percent // step + 1) * step


@contextlib.contextmanager
def heartbeat(label: str, out=None, every: float = 2.0):
    """Show that the enclosed work runs: ``label: N s`` every ``every`` seconds, then ``done``.

    On a terminal one line is rewritten in place; otherwise (logs, pipes, CI) a plain line
    is written each time, so nothing relies on carriage returns.  Work that ends within
    ``every`` seconds prints only the final line.
    """
    out = out if out is not None else sys.stderr
    terminal = _is_terminal(out)
    stop = threading.Event()
    start = time.perf_counter()

    def beat():
        while not stop.wait(every):
            text = f"{label}: {time.perf_counter() - start:.0f} s"
            out.write(f"\r{text}" if terminal else f"{text}\n")
            out.flush()

    thread = threading.Thread(target=beat, daemon=True)
    thread.start()
    ok = False
    try:
        yield
        ok = True
    finally:
        stop.set()
        thread.join()
        status = "done" if ok else "failed"
        out.write(f"{chr(13) if terminal else ''}{label}: {status} in "
                  f"{time.perf_counter() - start:.1f} s\n")
        out.flush()


#: ``--denominator`` of identify (and, with the pooled default added, sweep).
DENOMINATOR_HELP = ("how the LRM's denominator is estimated: ls (least squares, the paper) or iv "
                    "(instrumental variables from a first fit; removes the noise-induced bias, "
                    "see docs/uncertainty.md); default: ls for a model with a denominator, "
                    "nothing to choose for lpm")
#: ``--denominator`` of sweep: with ``--pool`` the groups are fitted as pooled experiments,
#: whose default is IV (lcmr_xr.settings.POOLED_DEFAULT_DENOMINATOR).
SWEEP_DENOMINATOR_HELP = DENOMINATOR_HELP.replace(
    "default: ls for a model with a denominator,",
    "default: ls for a model with a denominator (iv for the --pool groups: pooled experiments),")
