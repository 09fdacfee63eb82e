"""Benchmark of the compiled local-model kernel (run as a script; prints a table).

Everything issue 12 asks for, in one run, with the user's default thread settings
(nothing is exported here: no BLAS or numba thread variables):

* HDD experiment (N = 3600: M = 1800 slow bins, nz = 5, nr = 4, n = 30, degrees
  (3, 3, 3)): kernel and ``identify`` times with covariance None / "diag" / "full"
  (``identify(covariance=True)`` is the P_std path: it needs the full cross-row
  covariance); ratios to the per-bin lstsq oracle of the tests with and without
  covariance, and the agreement with it; ``identify(window="auto")`` (three candidate
  windows) against one fixed window;
* the same on complex data without conjugate symmetry (the kernel fits all bins);
* window n = 100 vs n = 10 (fit, covariance None);
* M = 2**19 slow bins, covariance None, one thread, and 2 threads vs 1 (``--only-big``
  runs only this part);
* first call with an empty numba cache, and a new process with a warm cache to its first
  ``identify`` result, split into its steps (median of 5 processes, wall and CPU), and
  its floor: the imports lcmr_xr cannot avoid (numpy, xarray with pandas, the dask.array
  xarray imports, numba with the scipy.linalg and registries of its target set-up)
  against lcmr_xr's own steps; the processes have Python's bytecode, as an installed
  package has; the compile time of
  each version of the compiled loop (least squares, instrumental variables, pooled, pooled
  with instrumental variables: what a cold ``make test`` pays; least squares and IV are
  one version), the first ``identify`` with the default window (``"auto"``: least
  squares and the IV twin); where the first call's compile time goes (numba's compile
  events: LLVM against numba's own passes, the loop against its helpers; and the same
  with ``NUMBA_OPT=0`` in that child process: the floor without LLVM's optimisation);
  the kernel alone on plain
  arrays, without xarray (``--only-start`` runs only this part);
* ``identify`` with a second process keeping one core busy vs without (``--no-busy``
  skips it);
* noiseless HDD experiments with N = 3600, 36000, 180000: flagged bins and median error
  against the true FRF (``--no-noiseless`` skips it).

The oracle runs with one BLAS thread (its best case; with threaded BLAS on a loaded
machine it was measured 100x slower).

Ratios are against baselines measured in the same process; each time is the best of a
few repeats.  CPU times (``time.process_time``, all threads of the process) are printed
beside wall times, and ratios on both: on a shared machine the wall times of a few
tens of milliseconds wait for the cores, the CPU times show what the code costs.
"""

import argparse
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "tests"))
from _lrm_oracle import oracle_local_model, resonant_system  # noqa: E402

import numba  # noqa: E402
from threadpoolctl import threadpool_limits  # noqa: E402

import lcmr_xr  # noqa: E402
from lcmr_xr import hdd  # noqa: E402
from lcmr_xr.kernels.identification import experiment_spectra  # noqa: E402
from lcmr_xr.kernels.local_models import local_model  # noqa: E402

KW = {"half_width": 30, "degrees": (3, 3, 3)}


def best_time(fn, repeat=3):
    """Best wall and CPU time of ``repeat`` calls, as an array ``[wall, cpu]``."""
    wall, cpu = np.inf, np.inf
    for _ in range(repeat):
        t0, c0 = time.perf_counter(), time.process_time()
        fn()
        wall = min(wall, time.perf_counter() - t0)
        cpu = min(cpu, time.process_time() - c0)
    return np.array([wall, cpu])


def _pair(x, digits):
    """``wall / cpu`` of a time or ratio pair."""
    return f"{x[0]:.{digits}f} / {x[1]:.{digits}f}"


def hdd_spectra(n_samples=3600):
    exp = hdd.simulate(n_samples=n_samples, noise=True, seed=1)
    arrays = [np.asarray(exp[v].transpose(..., d, "input" if v != "y" else "output"))
              for v, d in (("r", "time"), ("u", "time"), ("y", "slow_time"))]
    R, Z = experiment_spectra(*arrays, factor=int(exp.attrs["factor"]))
    return exp, R, Z


def oracle_section(rows, label, R, Z, every=10):
    """Kernel vs the per-bin lstsq oracle on every ``every``-th bin (scaled to all)."""
    m = R.shape[0]
    bins = np.arange(0, m, every)
    t_k = {cov: best_time(lambda c=cov: local_model(R, Z, covariance=c, **KW))
           for cov in (None, "diag", "full")}
    # the oracle at its best: one BLAS thread (threaded BLAS on its small per-bin
    # matrices is many times slower on a loaded machine)
    with threadpool_limits(1):
        t0, c0 = time.perf_counter(), time.process_time()
        ref = oracle_local_model(R, Z, 30, (3, 3, 3), bins=bins)
        t_oracle = np.array([time.perf_counter() - t0, time.process_time() - c0]) * m / len(bins)
        t0, c0 = time.perf_counter(), time.process_time()
        oracle_local_model(R, Z, 30, (3, 3, 3), bins=bins, covariance=False)
        t_plain = np.array([time.perf_counter() - t0, time.process_time() - c0]) * m / len(bins)
    fit = local_model(R, Z, **KW)
    ok = bins[~fit.ill_posed[bins]]

    def rel(a, b):
        return float(np.max(np.abs(a[ok] - b[ok]) / np.abs(b[ok])))

    cov_rel = float(np.max(np.linalg.norm(fit.G_cov[ok] - ref["G_cov"][ok], axis=(1, 2))
                           / np.linalg.norm(ref["G_cov"][ok], axis=(1, 2))))
    for cov, t in t_k.items():
        rows.append((f"{label}: kernel covariance={cov!r} [s] (wall / cpu)", _pair(t, 4)))
    rows.append((f"{label}: lstsq oracle with covariance, all bins [s] (wall / cpu)",
                 _pair(t_oracle, 2)))
    rows.append((f"{label}: plain lstsq fit (no covariance), all bins [s] (wall / cpu)",
                 _pair(t_plain, 2)))
    rows.append((f"{label}: oracle / kernel 'full' (wall / cpu)",
                 _pair(t_oracle / t_k["full"], 1)))
    rows.append((f"{label}: plain fit / kernel None (wall / cpu)", _pair(t_plain / t_k[None], 1)))
    # per bin and normwise: an elementwise ratio is dominated by entries many orders below
    # their neighbours (HDD, slow Nyquist bin: an entry of 2e-6 beside 1 differs by 1e-5
    # of itself, 8e-10 of the bin's G)
    g_rel = float(np.max(np.linalg.norm(fit.G[ok] - ref["G"][ok], axis=(1, 2))
                         / np.linalg.norm(ref["G"][ok], axis=(1, 2))))
    rows.append((f"{label}: max rel diff G per bin (normwise) / G elementwise / T / noise var / G_cov",
                 f"{g_rel:.1e} / {rel(fit.G, ref['G']):.1e} / {rel(fit.T, ref['T']):.1e} / "
                 f"{rel(fit.noise_variance, ref['noise_variance']):.1e} / {cov_rel:.1e}"))
    rows.append((f"{label}: ill-posed bins / bins with dropped terms",
                 f"{int(fit.ill_posed.sum())} / {int((fit.dropped > 0).sum())}"))
    return t_oracle, t_plain


#: The steps of a new process to its first result, each timed (wall and CPU seconds) in
#: the order in which they happen anyway, each import made explicit.  ``STEP`` marks the
#: end of a step; the first step is the interpreter's own start (from the parent's
#: ``perf_counter`` at the spawn, passed as ``SPAWN``: the clock is system-wide).  The
#: steps marked ``floor`` are imports that lcmr_xr cannot avoid: numpy; xarray with
#: pandas (any labelled function); dask and dask.array, which xarray imports whenever dask
#: is installed (``as_compatible_data``, on the first variable built from a numpy array
#: and on every output of an eager ``xarray.apply_ufunc``, asks for dask's array type;
#: ``is_duck_dask_array`` imports dask itself); numba; scipy.linalg, which numba imports
#: when its CPU target is set up (it looks for a BLAS); the rest of that set-up (numba's
#: typing and lowering registries, on the first compiled call or cache load, whatever the
#: function).
_STEPS = """
import sys
import time
marks = [(time.perf_counter() - SPAWN, time.process_time())]
def STEP():
    marks.append((time.perf_counter() - SPAWN, time.process_time()))
"""
_STEPS_END = """
walls = [marks[0][0]] + [b[0] - a[0] for a, b in zip(marks, marks[1:])]
cpus = [marks[0][1]] + [b[1] - a[1] for a, b in zip(marks, marks[1:])]
print(*walls, *cpus)
"""
_REFRESH = """
from numba.core.registry import cpu_target
cpu_target.target_context.refresh()
"""
#: A new process to its first ``identify`` result: the HDD experiment built from plain
#: arrays (``lcmr_xr.experiment``), as a user's script would.  Steps: python start,
#: numpy, xarray and pandas, lcmr_xr's own modules (``import lcmr_xr`` alone imports them
#: on first use; explicit here), dask.array (xarray's), the experiment, numba, scipy.linalg
#: (numba's), numba's target set-up, lcmr_xr's compiled module (its ``njit`` functions),
#: and the ``identify`` call itself (reading the cache and computing).
_FIRST_IDENTIFY_STEPS = (
    ("python start", True), ("numpy", True), ("xarray+pandas", True),
    ("lcmr_xr modules", False), ("dask.array (xarray's)", True), ("experiment", False),
    ("numba", True), ("scipy.linalg (numba's)", True), ("numba target set-up", True),
    ("compiled module", False), ("identify", False))
_FIRST_IDENTIFY = _STEPS + """
import numpy as np
STEP()
import xarray
STEP()
import lcmr_xr
import lcmr_xr.experiment, lcmr_xr.identification
STEP()
import dask.array
STEP()
d = np.load(PATH)
exp = lcmr_xr.experiment(d["r"], d["u"], d["y"], factor=int(d["factor"]),
                         sampling_period=float(d["th"]))
STEP()
import numba
STEP()
import scipy.linalg
STEP()
""" + _REFRESH + """
STEP()
from lcmr_xr.kernels import local_model_bins
STEP()
lcmr_xr.identify(exp, window=30)
STEP()
""" + _STEPS_END
#: The kernel alone on plain arrays: ``import lcmr_xr`` and the kernels import neither
#: xarray nor pandas (checked: the script fails if they were imported).  Steps: python
#: start, numpy, numba, scipy.linalg and the rest of numba's target set-up, lcmr_xr's
#: kernel modules, the ``local_model`` call.
_FIRST_KERNEL_STEPS = (
    ("python start", True), ("numpy", True), ("numba", True),
    ("scipy.linalg (numba's)", True), ("numba target set-up", True),
    ("lcmr_xr kernel modules", False), ("local_model", False))
_FIRST_KERNEL = _STEPS + """
import numpy as np
STEP()
import numba
STEP()
import scipy.linalg
STEP()
""" + _REFRESH + """
STEP()
import lcmr_xr
from lcmr_xr.kernels.local_models import local_model
from lcmr_xr.kernels import local_model_bins
STEP()
R = np.exp(2j * np.pi * np.random.default_rng(0).random((200, 4)))
Z = np.random.default_rng(1).standard_normal((200, 5)) + 0j
local_model(R, Z, half_width=30, degrees=(3, 3, 3), covariance="full")
STEP()
assert "xarray" not in sys.modules and "pandas" not in sys.modules
""" + _STEPS_END
#: Imports every module the timed processes import (nothing compiled): Python's bytecode
#: cache is then written before the timed processes start.
_PRIME = """
import numpy, xarray, dask.array, numba, scipy.linalg
import lcmr_xr, lcmr_xr.experiment, lcmr_xr.identification
from lcmr_xr.kernels import local_model_bins, local_models
""" + _REFRESH
#: An empty cache, each version of the compiled loop on its first call in one process,
#: in the order ``make test`` meets them: least squares (everybody's first call),
#: instrumental variables on one record, pooled experiments with least squares, pooled
#: with instrumental variables (``identify``'s default for pooled experiments).  CPU
#: seconds of each first call (compiling is single-threaded; the wall time waits for
#: the cores on a shared machine).
_COLD_VERSIONS = """
import time
import numpy as np
from lcmr_xr.kernels.local_models import local_model
rng = np.random.default_rng(0)
R = np.exp(2j * np.pi * rng.random((2, 200, 4)))
Z = rng.standard_normal((2, 200, 5)) + 0j
kw = dict(half_width=30, degrees=(3, 3, 3), covariance="full")
calls = [lambda: local_model(R[0], Z[0], **kw),
         lambda: local_model(R[0], Z[0], instruments=0.9 * Z[0], **kw),
         lambda: local_model(R, Z, experiment_axis=0, **kw),
         lambda: local_model(R, Z, experiment_axis=0, instruments=0.9 * Z, **kw)]
out = []
for call in calls:
    c0 = time.process_time()
    call()
    out.append(time.process_time() - c0)
from lcmr_xr.kernels import local_model_bins
print(*out, len(local_model_bins.fit_bins.signatures))
"""
#: Where an empty cache's first call goes: the one-record version of the compiled loop
#: (least squares and IV share it) compiled for a least-squares call with full covariance,
#: timed by numba's compile events.  Per compiled function its own CPU seconds (those of
#: the functions it calls, compiled while it is typed, subtracted), and the CPU seconds
#: under numba's LLVM lock (LLVM's optimisation and machine code; the rest is numba's own
#: Python: bytecode analysis, SSA, typing, lowering to LLVM IR).  ``NUMBA_OPT`` is the
#: child process's own environment (set by the caller for the floor without LLVM's
#: optimisation; never in the user's process).  Prints the total, the LLVM part, the loop's
#: own and its LLVM part, the helpers' (number of functions) and numba's overloads'
#: (``impl``: ``np.empty`` per shape and dtype, array views, ``min``/``max``).
_COLD_BREAKDOWN = """
import time
import numpy as np
from numba.core import event
from lcmr_xr.kernels.local_models import local_model
stack, own, llvm = [], {}, {}
class Compile(event.Listener):
    def on_start(self, ev):
        now = time.process_time()
        if stack:
            stack[-1][1] += now - stack[-1][2]
        stack.append([ev.data["dispatcher"].py_func.__name__, 0.0, now])
    def on_end(self, ev):
        now = time.process_time()
        name, acc, t0 = stack.pop()
        own[name] = own.get(name, 0.0) + acc + now - t0
        if stack:
            stack[-1][2] = now
class Llvm(event.Listener):
    def on_start(self, ev):
        self.t0 = time.process_time()
    def on_end(self, ev):
        name = stack[-1][0] if stack else ""
        llvm[name] = llvm.get(name, 0.0) + time.process_time() - self.t0
event.register("numba:compile", Compile())
event.register("numba:llvm_lock", Llvm())
rng = np.random.default_rng(0)
R = np.exp(2j * np.pi * rng.random((200, 4)))
Z = rng.standard_normal((200, 5)) + 0j
c0 = time.process_time()
local_model(R, Z, half_width=30, degrees=(3, 3, 3), covariance="full")
total = time.process_time() - c0
helpers = [k for k in own if k not in ("fit_bins", "impl")]
print(total, sum(llvm.values()), own["fit_bins"], llvm.get("fit_bins", 0.0),
      sum(own[k] for k in helpers), len(helpers), own.get("impl", 0.0))
"""
#: An empty cache, the HDD experiment's first ``identify`` with the default window
#: (``"auto"``: the least-squares fit and the instrumental-variables twin of its widest
#: window, both through the one compiled version of the loop): wall and CPU seconds of the call
#: (the second process of ``lcmr_xr.kernels.compile_ahead`` not counted in the CPU).
_COLD_DEFAULT = """
import time
import numpy as np
import lcmr_xr
d = np.load(PATH)
exp = lcmr_xr.experiment(d["r"], d["u"], d["y"], factor=int(d["factor"]),
                         sampling_period=float(d["th"]))
w0, c0 = time.perf_counter(), time.process_time()
lcmr_xr.identify(exp)
print(time.perf_counter() - w0, time.process_time() - c0)
"""


def _start_env(tmp):
    """The environment of the start-time processes: numba's cache and Python's bytecode
    cache in ``tmp``.  An installed package has its bytecode (pip writes it); a shell
    with ``PYTHONDONTWRITEBYTECODE`` set (as this project's is) would otherwise have every
    process compile lcmr_xr's sources again: 0.085 s CPU of its warm start (measured)."""
    env = dict(os.environ, NUMBA_CACHE_DIR=os.path.join(tmp, "numba"),
               PYTHONPYCACHEPREFIX=os.path.join(tmp, "pycache"))
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    subprocess.run([sys.executable, "-c", _PRIME], env=env, check=True, capture_output=True)
    return env


def _steps(code, env):
    """Wall and CPU seconds of each step of ``code`` (``_STEPS``) in a new process."""
    code = code.replace("SPAWN", repr(time.perf_counter()))
    out = subprocess.run([sys.executable, "-c", code], env=env, check=True,
                         capture_output=True, text=True).stdout.split()
    times = np.array([float(x) for x in out])
    return times.reshape(2, -1)  # wall, cpu


def _step_rows(rows, what, names, times, goal=""):
    """Rows of one start measurement: the median total, its steps, and the part of it that
    lcmr_xr cannot avoid (the ``floor`` steps) against its own part."""
    med = np.median(times, axis=0)  # (wall / cpu, step)
    total = np.median(times.sum(axis=2), axis=0)
    rows.append((f"{what} [s] (wall / CPU; median of {len(times)}){goal}",
                 f"{total[0]:.2f} / {total[1]:.2f}"))
    rows.append(("  " + " / ".join(name for name, _ in names) + " [s] (CPU)",
                 " / ".join(f"{t:.3f}" for t in med[1])))
    rows.append(("  the same [s] (wall)", " / ".join(f"{t:.3f}" for t in med[0])))
    floor = np.array([floor for _, floor in names])
    part = np.median(times[:, :, floor].sum(axis=2), axis=0)
    own = np.median(times[:, :, ~floor].sum(axis=2), axis=0)
    rows.append(("  imports lcmr_xr cannot avoid (" + ", ".join(
        name for name, f in names if f) + ") / lcmr_xr's own steps [s] (CPU; wall)",
        f"{part[1]:.2f} / {own[1]:.2f}; {part[0]:.2f} / {own[0]:.2f}"))


def start_times(rows, exp, repeat=5):
    """First call in a new process: empty numba cache (compiles), then warm cache (median
    of ``repeat`` fresh processes), split into the steps of ``_FIRST_IDENTIFY``; the
    kernel alone on plain arrays (``local_model``, steps of ``_FIRST_KERNEL``); and the
    compile time of every version of the compiled loop (``_COLD_VERSIONS``).  The
    processes have Python's bytecode, as an installed package has (``_start_env``)."""
    with tempfile.TemporaryDirectory() as tmp:
        data = os.path.join(tmp, "exp.npz")
        np.savez(data, r=exp.r.values, u=exp.u.values, y=exp.y.values,
                 factor=int(exp.attrs["factor"]), th=float(exp.time[1] - exp.time[0]))
        code = _FIRST_IDENTIFY.replace("PATH", repr(data))
        # the same without the second process first (its own empty cache), then with it
        serial = _steps(code, dict(_start_env(os.path.join(tmp, "serial")),
                                   LCMR_XR_COMPILE_AHEAD="0"))
        env = _start_env(tmp)
        cold = _steps(code, env)
        time.sleep(5)  # (the second process, if still compiling, finishes alone)
        # alternating, so that a change of the machine's load hits both alike
        warm, kernel = [], []
        for _ in range(repeat):
            warm.append(_steps(code, env))
            kernel.append(_steps(_FIRST_KERNEL, env))
    rows.append(("new process to first identify, empty cache (compiles; the helpers "
                 "also in a second process) [s] (goal < 15)",
                 f"{cold[0].sum():.1f} (CPU {cold[1].sum():.1f})"))
    rows.append(("  the same without the second process (LCMR_XR_COMPILE_AHEAD=0) [s]",
                 f"{serial[0].sum():.1f} (CPU {serial[1].sum():.1f})"))
    _step_rows(rows, "new process to first identify, warm cache", _FIRST_IDENTIFY_STEPS,
               np.array(warm), " (goal < 1)")
    _step_rows(rows, "new process to first local_model result (plain arrays, no xarray), "
               "warm cache", _FIRST_KERNEL_STEPS, np.array(kernel), " (goal < 1)")
    with tempfile.TemporaryDirectory() as tmp:
        env = _start_env(tmp)
        *cold, versions = [float(x) for x in subprocess.run(
            [sys.executable, "-c", _COLD_VERSIONS], env=env, check=True, capture_output=True,
            text=True).stdout.split()]
    rows.append(("empty cache, first call CPU [s]: least squares / IV / pooled / pooled IV "
                 "(one process, in this order; IV shares the version of least squares; this "
                 "process's CPU, the helpers' second process not counted)",
                 " / ".join(f"{t:.1f}" for t in cold) + f" ({versions:.0f} compiled versions)"))
    compile_breakdown(rows)
    with tempfile.TemporaryDirectory() as tmp:
        data = os.path.join(tmp, "exp.npz")
        np.savez(data, r=exp.r.values, u=exp.u.values, y=exp.y.values,
                 factor=int(exp.attrs["factor"]), th=float(exp.time[1] - exp.time[0]))
        env = _start_env(tmp)
        wall, cpu = (float(x) for x in subprocess.run(
            [sys.executable, "-c", _COLD_DEFAULT.replace("PATH", repr(data))], env=env,
            check=True, capture_output=True, text=True).stdout.split())
    rows.append(("empty cache, first identify with the default window (auto: least squares "
                 "and its IV twin), the call alone [s] (wall / CPU of this process; goal < 15)",
                 f"{wall:.1f} / {cpu:.1f}"))


def compile_breakdown(rows):
    """Where an empty cache's first call goes (``_COLD_BREAKDOWN``), in a new process with
    numba's default optimisation level, and again with ``NUMBA_OPT=0`` in that process's
    environment (the floor without LLVM's optimisation)."""
    for opt in (None, "0"):
        with tempfile.TemporaryDirectory() as tmp:
            # the serial work: without the second process (lcmr_xr.kernels.compile_ahead)
            env = dict(_start_env(tmp), LCMR_XR_COMPILE_AHEAD="0")
            if opt is not None:
                env["NUMBA_OPT"] = opt
            load = os.getloadavg()[0]
            out = [float(x) for x in subprocess.run(
                [sys.executable, "-c", _COLD_BREAKDOWN], env=env, check=True,
                capture_output=True, text=True).stdout.split()]
        rows.append(("empty cache, first least-squares call CPU [s]" + (
            "" if opt is None else f" with NUMBA_OPT={opt} (no LLVM optimisation: the floor)")
            + ": total / LLVM / fit_bins's own (its LLVM) / helpers (number) / numba's "
            f"overloads (load {load:.1f})",
            f"{out[0]:.1f} / {out[1]:.1f} / {out[2]:.1f} ({out[3]:.1f}) / {out[4]:.1f} "
            f"({out[5]:.0f}) / {out[6]:.1f}"))


def busy_section(rows, exp):
    """identify on an idle machine vs with another process spinning on one core."""
    def run():
        lcmr_xr.identify(exp, window=30)

    idle, _ = best_time(run)
    spinner = subprocess.Popen([sys.executable, "-c", "while True: pass"])
    try:
        time.sleep(0.5)
        busy, _ = best_time(run)
    finally:
        spinner.kill()
        spinner.wait()
    rows.append(("identify HDD, covariance: idle [s]", f"{idle:.3f}"))
    rows.append(("identify HDD, covariance: 1 core busy elsewhere [s]", f"{busy:.3f}"))
    rows.append(("  busy / idle (goal <= 2)", f"{busy / idle:.2f}"))


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--no-big", action="store_true", help="skip the M = 2**19 part")
    parser.add_argument("--only-big", action="store_true",
                        help="run only the M = 2**19 part (the goal < 4 s on one thread)")
    parser.add_argument("--no-start", action="store_true",
                        help="skip the first-call (compile) and warm-cache measurements")
    parser.add_argument("--only-start", action="store_true",
                        help="run only the first-call (compile) and warm-cache measurements")
    parser.add_argument("--no-busy", action="store_true",
                        help="skip identify with a busy second process")
    parser.add_argument("--no-noiseless", action="store_true",
                        help="skip the noiseless HDD experiments")
    args = parser.parse_args(argv)
    rows = [("numba threads (default)", str(numba.get_num_threads())),
            ("load average at the start (2 cores shared: compare within the run)",
             f"{os.getloadavg()[0]:.1f}")]
    if args.only_big or args.only_start:
        if args.only_big:
            big_section(rows)
        if args.only_start:
            start_times(rows, hdd.simulate(n_samples=3600, noise=True, seed=1))
        rows.append(("load average at the end", f"{os.getloadavg()[0]:.1f}"))
        _print(rows)
        return
    exp, R, Z = hdd_spectra()
    local_model(R[:100], Z[:100], half_width=30, covariance="full")  # load the compiled code
    t_oracle, t_plain = oracle_section(rows, "HDD M=1800", R, Z)
    # identify(covariance=True) is the P_std path (the default)
    for cov in (False, True):
        t_id = best_time(lambda c=cov: lcmr_xr.identify(exp, window=30, covariance=c))
        rows.append((f"identify HDD covariance={cov} [s] (wall / cpu)", _pair(t_id, 4)))
        if cov:
            rows.append(("  oracle with covariance / identify (goal >= 100; wall / cpu)",
                         _pair(t_oracle / t_id, 1)))
        else:
            rows.append(("  plain lstsq fit / identify without covariance (wall / cpu)",
                         _pair(t_plain / t_id, 1)))
    rows.append(("  plain lstsq fit / identify with covariance (goal >= 20; wall / cpu)",
                 _pair(t_plain / t_id, 1)))
    # window="auto" fits three candidate windows with covariance: its cost against one
    t_auto = best_time(lambda: lcmr_xr.identify(exp, window="auto"))
    rows.append(("  identify window='auto' / window=30, both with covariance (goal < 3; "
                 "wall / cpu)", _pair(t_auto / t_id, 2)))
    Rc, Zc, _, _ = resonant_system(1800, 5, 4, seed=0, noise=1e-3)
    oracle_section(rows, "complex M=1800", Rc, Zc)

    t10 = best_time(lambda: local_model(Rc, Zc, half_width=10, degrees=(1, 1, 1),
                                        covariance=None), repeat=7)
    t100 = best_time(lambda: local_model(Rc, Zc, half_width=100, degrees=(1, 1, 1),
                                         covariance=None), repeat=7)
    rows.append(("fit time n=100 / n=10, degrees (1,1,1) (goal <= 1.5; wall / cpu)",
                 _pair(t100 / t10, 2)))
    t30, _ = best_time(lambda: local_model(Rc, Zc, covariance=None, **KW))
    t100b, _ = best_time(lambda: local_model(Rc, Zc, half_width=100, degrees=(3, 3, 3),
                                             covariance=None))
    rows.append(("fit time n=100 / n=30, degrees (3,3,3)", f"{t100b / t30:.2f}"))

    if not args.no_big:
        big_section(rows)
    if not args.no_start:
        start_times(rows, exp)
    if not args.no_busy:
        busy_section(rows, exp)
    if not args.no_noiseless:
        noiseless_section(rows)
    rows.append(("load average at the end", f"{os.getloadavg()[0]:.1f}"))
    _print(rows)


def big_section(rows):
    """M = 2**19 slow bins of real-signal spectra, covariance=None: one thread (goal < 4 s,
    best of 2), 2 threads vs 1, and complex data (all bins fitted)."""
    big = 2**19
    rng = np.random.default_rng(1)
    # spectra of real signals, as every experiment has (half the bins are mirrored)
    Rb = np.fft.fft(rng.standard_normal((big, 4)), axis=0)
    Zb = np.fft.fft(rng.standard_normal((big, 5)), axis=0)
    default = numba.get_num_threads()
    numba.set_num_threads(1)
    w1, c1 = best_time(lambda: local_model(Rb, Zb, covariance=None, **KW), repeat=2)
    rows.append(("M=2**19 real-signal spectra, covariance=None, 1 thread [s] "
                 "(wall / cpu; goal < 4)", f"{w1:.2f} / {c1:.2f}"))
    if default > 1:
        numba.set_num_threads(2)
        w2, _ = best_time(lambda: local_model(Rb, Zb, covariance=None, **KW), repeat=2)
        rows.append(("  2 threads [s]", f"{w2:.2f}"))
        rows.append(("  1 thread / 2 threads (goal >= 1.6)", f"{w1 / w2:.2f}"))
    numba.set_num_threads(1)
    Zb = Zb + 1j * np.fft.fft(rng.standard_normal((big, 5)), axis=0)  # no symmetry
    wc, cc = best_time(lambda: local_model(Rb, Zb, covariance=None, **KW), repeat=1)
    rows.append(("M=2**19 complex data (all bins fitted), 1 thread [s] (wall / cpu)",
                 f"{wc:.2f} / {cc:.2f}"))
    numba.set_num_threads(default)


def noiseless_section(rows):
    """Noiseless HDD experiments: no flagged bin, error falling with the length."""
    for n_samples in (3600, 36000, 180000):
        exp = hdd.simulate(n_samples=n_samples, noise=False, seed=1)
        t0 = time.perf_counter()
        frf = lcmr_xr.identify(exp, window=30, covariance=False, errors="ignore")
        wall = time.perf_counter() - t0
        true = hdd.true_frf(frf.frequency[1:]).values  # (DC: the VCM is infinite)
        err = np.median(np.abs(frf.P.values[1:] - true) / np.abs(true))
        rows.append((f"noiseless HDD N={n_samples}: flagged slow bins / median rel error / "
                     "identify [s]",
                     f"{int(frf.ill_posed.sum() + frf.s_singular.sum())} / {err:.1e} / "
                     f"{wall:.2f}"))


def _print(rows):
    width = max(len(r[0]) for r in rows)
    for name, value in rows:
        print(f"{name:<{width}}  {value}")


if __name__ == "__main__":
    main()
