"""Compiling the local model's helpers ahead, in a second process, on an empty cache.

A new install's first local model compiles :func:`.local_model_bins.fit_bins` (numba,
``cache=True``), and with it the sixteen helpers it calls: about 16 s of one core, of
which the helpers are about 6 s, compiled one after another as ``fit_bins``'s type
inference meets their calls.  numba compiles one function at a time per process (its
compiler lock), but a second process can compile the helpers into the same on-disk
cache meanwhile: when ``fit_bins``'s type inference then meets a helper that the second
process has saved, numba loads it from the cache instead of compiling it.  The second
process compiles them in the reverse of the order in which ``fit_bins`` needs them, so
that the two meet in the middle (measured: ``docs/architecture.md``, "A new process to
its first result").

This is an optimisation only, never needed for a result: the second process writes
nothing but numba's cache files (numba writes each through a temporary file and a
rename), the first process compiles whatever is not there yet itself, and a second
process that fails or is slow costs nothing but its own CPU.  It starts only

* when ``fit_bins`` actually starts compiling its one-record version (numba's compile
  event, which fires after numba found no cached version: a warm cache starts nothing),
  once per process;
* when more than one CPU is available to this process (on one CPU the two processes
  would share it);
* when ``sys.executable`` is a Python interpreter: not in a frozen application, nor in a
  program that embeds Python (``-c`` would start that program again);
* unless the environment variable ``LCMR_XR_COMPILE_AHEAD`` is ``0`` (``1`` or unset:
  on).  Set it to ``0`` where starting processes is unwelcome, e.g. many dask workers
  starting together on an empty cache.

The helpers' argument types are listed in :data:`HELPER_SIGNATURES`, in the order the
second process compiles them; ``tests/test_compile_ahead.py`` checks them against
``fit_bins``'s type inference, so that a change of a helper's arguments cannot silently
turn this into wasted work.
"""

from __future__ import annotations

import os
import subprocess
import sys
import threading

#: The environment variable that switches the second process off (``0``) or on (``1``,
#: the default when unset).
SETTING = "LCMR_XR_COMPILE_AHEAD"

#: The helpers of ``fit_bins``'s one-record version (``pool=None``; least squares and
#: instrumental variables share it) with their argument types, in the reverse of the
#: order in which ``fit_bins``'s type inference needs them.  Types: ``DTYPE Nd`` a
#: C-contiguous aligned array (``readonly`` when it is one), else a scalar type's name.
HELPER_SIGNATURES = (
    ("_iv_tau", "int64 1d, float64 1d, float64 2d, float64 2d, float64 3d, float64 3d, "
     "float64 3d, float64 3d, float64 2d, float64 2d, float64 3d, float64 3d, "
     "complex128 2d, complex128 2d, complex128 2d, bool"),
    ("_row_gains", "complex128 3d, int64, int64, int64, int64, int64, int64, int64 1d, "
     "complex128 2d, float64 1d, float64 1d, complex128 2d, int64 1d, complex128 2d, "
     "int64, int64, float64 1d, float64 1d, float64 1d, float64 2d, float64 2d, "
     "float64 2d, int64 1d, complex128 3d, none, bool, complex128 1d, complex128 2d, "
     "complex128 2d, float64 2d, float64 2d, complex128 2d, complex128 1d, float64 2d, "
     "float64 2d, float64 2d, float64 2d, float64 2d, float64 2d, complex128 1d, "
     "complex128 1d"),
    ("_project_kept", "complex128 3d, int64, int64, int64, int64, int64, float64 1d, "
     "int64, int64 1d, complex128 2d, float64 2d, float64 2d, float64 2d, int64 1d, "
     "complex128 3d, none, complex128 1d, complex128 2d, float64 2d, float64 2d"),
    ("_iv_row", "complex128 2d, int64, int64, int64, int64, int64 1d, complex128 2d, "
     "float64 1d, complex128 3d, complex128 3d, float64 1d, complex128 2d, int64 1d, "
     "complex128 2d, complex128 2d, complex128 1d, complex128 1d, float64"),
    ("_lu_solve", "complex128 2d, int64, int64 1d, complex128 1d"),
    ("_tail_solve", "complex128 2d, int64, int64, complex128 1d, complex128 1d"),
    ("_chol_solve", "complex128 2d, int64, complex128 1d, complex128 1d"),
    ("pivoted_cholesky", "complex128 2d, float64, complex128 2d, int64 1d, float64 1d"),
    ("_natural_min_pivot", "complex128 2d, complex128 2d"),
    ("_gram_rows", "float64 2d, float64 2d, int64, complex128 2d"),
    ("_moment", "complex128 1d, int64, int64"),
    ("cholesky_planes", "float64 2d, float64 2d, int64, float64 1d, float64 2d"),
    ("_failed_bin", "int64, int64, complex128 3d, complex128 3d, complex128 3d, "
     "float64 1d, bool 1d, int64 1d, complex128 3d, float64 3d"),
    ("_advance", "complex128 3d, complex128 3d, int64, int64, bool, bool 1d, int64, "
     "int64, int64, int64 1d readonly, int64 1d readonly, float64 2d, float64 2d, "
     "float64 1d, complex128 1d, float64 1d, complex128 2d"),
    ("_products", "complex128 3d, complex128 3d, int64, int64, int64 1d readonly, "
     "int64 1d readonly, complex128 1d, complex128 1d"),
    ("_recurrence", "int64, int64"),
)

_lock = threading.Lock()
_started = False


def enabled() -> bool:
    """Whether the second process may start (:data:`SETTING`).

    Returns
    -------
    bool
        False when ``LCMR_XR_COMPILE_AHEAD`` is ``0``; True when it is ``1`` or unset.

    Raises
    ------
    ValueError
        For any other value (a typo must not silently mean on or off).
    """
    value = os.environ.get(SETTING, "1").strip()
    if value not in ("0", "1"):
        raise ValueError(
            f"the environment variable {SETTING}={os.environ[SETTING]!r} is not 0 or 1: "
            f"set it to 0 to compile without a second process, to 1 (or unset it) to "
            f"let lcmr_xr compile its helpers in a second process on an empty cache")
    return value == "1"


def available_cpus() -> int:
    """CPUs this process may run on (its affinity where the platform tells it)."""
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def parse_type(text: str):
    """The numba type of one entry of :data:`HELPER_SIGNATURES` (``"float64 2d"``,
    ``"int64 1d readonly"``, ``"int64"``, ``"bool"``, ``"none"``)."""
    from numba.core import types

    words = text.split()
    scalar = {"bool": types.boolean, "none": types.none}.get(words[0])
    if scalar is None:
        scalar = getattr(types, words[0])
    if len(words) == 1:
        return scalar
    ndim = int(words[1].removesuffix("d"))
    return types.Array(scalar, ndim, "C", readonly=words[2:] == ["readonly"])


def signature(entry: str) -> tuple:
    """The argument types of one :data:`HELPER_SIGNATURES` entry, as a tuple."""
    return tuple(parse_type(t) for t in entry.split(","))


def _one_record(args) -> bool:
    """Whether ``fit_bins``'s argument types are those of its one-record version:
    ``pool`` (its second last argument) None."""
    from numba.core import types

    return len(args) >= 2 and isinstance(args[-2], types.NoneType)


#: The second process's program: it must compile the same source files as this process,
#: by the same paths (numba makes the cache directory from a source file's path as
#: imported, symbolic links not resolved), so it imports from this process's path (its
#: arguments after the first: not ``-c``'s current directory, whose modules this process
#: may never import), this copy of lcmr_xr, spelled as this process imported it, put
#: first unless it is on that path already (an installed package); and it stops if
#: another copy or spelling would be imported.
_BOOT = """
import os, sys
root = os.path.abspath(sys.argv[1])
sys.path[:] = sys.argv[2:]
if root not in {os.path.abspath(p) for p in sys.path if p}:
    sys.path.insert(0, root)
import lcmr_xr
if os.path.dirname(os.path.dirname(os.path.abspath(lcmr_xr.__file__))) != root:
    sys.exit(2)
from lcmr_xr.kernels.compile_ahead import main
sys.exit(main())
"""


def _root() -> str:
    """The directory holding this copy of the ``lcmr_xr`` package, spelled as imported
    (symbolic links not resolved: numba's cache directory depends on the spelling)."""
    return os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def _command() -> list[str] | None:
    """The second process's command line, or None where there is no Python to run: no
    executable, a frozen application (``sys.executable`` is the application), or an
    interpreter embedded in a program (``sys.executable`` that program, e.g. ``maya``,
    ``uwsgi``, ``pythonservice.exe``), which ``-c`` would start again."""
    if not sys.executable or not os.path.exists(sys.executable):
        return None
    if getattr(sys, "frozen", False):
        return None
    name = os.path.basename(sys.executable).lower()
    if not name.startswith("python") or name.startswith("pythonservice"):
        return None
    return [sys.executable, "-c", _BOOT, _root(), *(p for p in sys.path if isinstance(p, str))]


def start() -> subprocess.Popen | None:
    """Start the second process once per process, if :func:`enabled` and more than one
    CPU is available; None when it did not start (now or before).

    Returns
    -------
    subprocess.Popen or None
        The second process (already waited for by a daemon thread, so that it never
        lingers as a zombie), or None.
    """
    global _started
    with _lock:
        if _started:
            return None
        _started = True
    if not enabled() or available_cpus() < 2:
        return None
    command = _command()
    if command is None:
        return None
    options = {}
    if hasattr(subprocess, "CREATE_NO_WINDOW"):  # (Windows: no console window for it)
        options["creationflags"] = subprocess.CREATE_NO_WINDOW
    try:
        process = subprocess.Popen(command, stdin=subprocess.DEVNULL,
                                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                   close_fds=True, **options)
    except (OSError, subprocess.SubprocessError):  # (compiling here is the normal path)
        return None
    try:
        threading.Thread(target=process.wait, name="lcmr_xr compile ahead",
                         daemon=True).start()
    except RuntimeError:  # (no thread to wait for it: a thread limit, shutdown)
        process.kill()
        process.wait()
        return None
    return process


def install(dispatcher) -> None:
    """Listen for ``dispatcher``'s (``fit_bins``'s) compiles: the second process starts
    on the first compile of its one-record version.  Reads :data:`SETTING` now, so that
    a wrong value is refused on import rather than inside numba's compiler.

    Parameters
    ----------
    dispatcher : numba dispatcher
        :func:`.local_model_bins.fit_bins`.
    """
    enabled()
    from numba.core import event

    class FirstCompile(event.Listener):
        """Fires after numba found no cached version, before it compiles."""

        def on_start(self, ev):
            # runs inside every numba compile of this process (the user's own functions
            # too): nothing may come out of it (a wrong SETTING local_model refuses itself)
            try:
                data = ev.data if isinstance(ev.data, dict) else {}
                if (data.get("dispatcher") is dispatcher
                        and _one_record(data.get("args", ()))):
                    start()
            except Exception:  # noqa: BLE001 (an optimisation only)
                pass

        def on_end(self, ev):
            pass

    event.register("numba:compile", FirstCompile())


def main() -> int:
    """The second process: compile each helper of :data:`HELPER_SIGNATURES` in turn
    (numba loads those already in the cache and saves the others).  A helper that fails
    to compile is skipped: the first process compiles what it needs itself."""
    from lcmr_xr.kernels import local_model_bins

    failed = 0
    for name, entry in HELPER_SIGNATURES:
        try:
            getattr(local_model_bins, name).compile(signature(entry))
        except Exception:  # noqa: BLE001 (an optimisation only: see the module notes)
            failed += 1
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
