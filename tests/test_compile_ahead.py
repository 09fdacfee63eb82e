"""The second compiling process (lcmr_xr.kernels.compile_ahead): it compiles exactly the
helpers that fit_bins calls, with the argument types fit_bins calls them with, into the
same cache; it starts once, only where it can help, and a wrong setting is refused."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest
from numba.core import compiler, event, typed_passes, types
from numba.core.compiler_machinery import FunctionPass, register_pass
from numba.core.registry import cpu_target

from lcmr_xr.kernels import compile_ahead, local_model_bins
from lcmr_xr.kernels.local_models import local_model


@register_pass(mutates_CFG=False, analysis_only=True)
class _KeepTypes(FunctionPass):
    """Ends a type-only pipeline: the compile result is the pipeline's state."""
    _name = "lcmr_xr_keep_types"

    def __init__(self):
        FunctionPass.__init__(self)

    def run_pass(self, state):
        state.cr = state
        return False


class _TypeOnly(compiler.CompilerBase):
    """numba's nopython pipeline up to type inference (dead branches pruned as for the
    real compile): which functions a function calls, with which argument types, without
    lowering it."""

    def define_pipelines(self):
        pm = compiler.DefaultPassBuilder.define_nopython_pipeline(self.state)
        cut = [p for p, _ in pm.passes].index(typed_passes.NopythonTypeInference) + 1
        pm.passes = pm.passes[:cut]
        pm.add_pass(_KeepTypes, "keep the types")
        pm._finalized = False
        pm.finalize()
        return [pm]


def _called(dispatcher, args):
    """(name, argument types) of every compiled function that ``dispatcher`` calls for
    ``args``, and of those they call, recursively."""
    flags = compiler.Flags()
    dispatcher.targetdescr.options.parse_as_flags(flags, dispatcher.targetoptions)
    state = compiler.compile_extra(cpu_target.typing_context, cpu_target.target_context,
                                   dispatcher.py_func, args, None, flags, {},
                                   pipeline_class=_TypeOnly)
    found = set()
    for expr, sig in state.calltypes.items():
        if getattr(expr, "op", None) != "call":
            continue
        callee = state.typemap[expr.func.name]
        if isinstance(callee, types.Dispatcher):
            key = (callee.dispatcher.py_func.__name__, tuple(sig.args))
            if key not in found:
                found.add(key)
                found |= _called(callee.dispatcher, sig.args)
    return found


@pytest.fixture(scope="module")
def one_record_signature():
    """fit_bins's one-record version's argument types, from a real local_model call."""
    rng = np.random.default_rng(0)
    R = np.exp(2j * np.pi * rng.random((60, 2)))
    Z = rng.standard_normal((60, 2)) + 0j
    local_model(R, Z, half_width=8, degrees=(1, 1, 1), covariance="full")
    (sig,) = [s for s in local_model_bins.fit_bins.signatures if compile_ahead._one_record(s)]
    return sig


def test_the_listed_helpers_are_exactly_those_fit_bins_calls(one_record_signature):
    listed = {(name, compile_ahead.signature(entry))
              for name, entry in compile_ahead.HELPER_SIGNATURES}
    called = _called(local_model_bins.fit_bins, one_record_signature)
    assert len(listed) == len(compile_ahead.HELPER_SIGNATURES)  # each helper once
    missing = sorted(called - listed)
    extra = sorted(listed - called)
    assert not missing and not extra, (
        "compile_ahead.HELPER_SIGNATURES is stale; fit_bins now calls "
        f"{missing} and no longer {extra}")


def test_every_listed_helper_is_compiled_and_cached_by_the_second_process(tmp_path):
    # the asking process imports this copy of lcmr_xr through a symbolic link put on its
    # path at run time (where the platform allows one): numba's cache directory is made
    # from the source files' paths as imported, so the second process must import the
    # same spelling, not the resolved one, for the asking process to find its work.  The
    # asking process is a script run in a directory holding a module named numba, which
    # it does not import (a script's path holds its own directory, not the current one):
    # nor may the second process (it imports from the asking process's path)
    root = compile_ahead._root()
    link = tmp_path / "link"
    try:
        link.symlink_to(root, target_is_directory=True)
        root = str(link)
    except OSError:  # (no symbolic links here: the plain path)
        pass
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"))
    env.pop(compile_ahead.SETTING, None)
    # the second process, run to its end by the asking process; then every helper loads
    # in the asking process, none compiles
    check = (
        f"import subprocess, sys\n"
        f"sys.path.insert(0, {root!r})\n"
        "from lcmr_xr.kernels import compile_ahead, local_model_bins as b\n"
        "done = subprocess.run(compile_ahead._command(), capture_output=True, text=True)\n"
        "assert done.returncode == 0, done.stderr\n"
        "hits = misses = 0\n"
        "for name, entry in compile_ahead.HELPER_SIGNATURES:\n"
        "    d = getattr(b, name)\n"
        "    d.compile(compile_ahead.signature(entry))\n"
        "    hits += sum(d.stats.cache_hits.values())\n"
        "    misses += sum(d.stats.cache_misses.values())\n"
        "print(b.__file__, hits, misses)\n")
    (tmp_path / "numba.py").write_text("raise ImportError('numba of the current directory')\n")
    script = tmp_path / "asking" / "check.py"
    script.parent.mkdir()
    script.write_text(check)
    out = subprocess.run([sys.executable, str(script)], env=env, cwd=tmp_path,
                         capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr
    source, hits, misses = out.stdout.split()
    assert source.startswith(root)  # (imported by the spelling asked for)
    assert (int(hits), int(misses)) == (len(compile_ahead.HELPER_SIGNATURES), 0)


@pytest.fixture
def spawns(monkeypatch):
    """compile_ahead.start with a fresh once-flag and a recording Popen."""
    calls = []

    class FakeProcess:
        def __init__(self, command, **kw):
            calls.append((command, kw))

        def wait(self):
            return 0

    monkeypatch.setattr(compile_ahead, "_started", False)
    monkeypatch.setattr(compile_ahead.subprocess, "Popen", FakeProcess)
    monkeypatch.setattr(compile_ahead, "available_cpus", lambda: 2)
    monkeypatch.delenv(compile_ahead.SETTING, raising=False)
    return calls


def test_starts_once_per_process_for_this_copy_of_lcmr_xr(spawns):
    assert compile_ahead.start() is not None
    assert compile_ahead.start() is None
    assert len(spawns) == 1
    command, kw = spawns[0]
    package = os.path.dirname(os.path.dirname(os.path.abspath(compile_ahead.__file__)))
    # then this process's path, from which the second process imports
    assert command == [sys.executable, "-c", compile_ahead._BOOT, os.path.dirname(package),
                       *(p for p in sys.path if isinstance(p, str))]
    assert "env" not in kw  # this process's environment: numba's cache directory
    assert kw["stdout"] is subprocess.DEVNULL and kw["stderr"] is subprocess.DEVNULL


@pytest.mark.parametrize("name", ["maya", "uwsgi", "myapp.exe", "pythonservice.exe"])
def test_does_not_start_where_the_executable_is_not_a_python(spawns, monkeypatch, tmp_path,
                                                            name):
    # an embedding application (its sys.executable its own program): "-c code" would
    # start another copy of that application
    program = tmp_path / name
    program.write_text("")
    monkeypatch.setattr(sys, "executable", str(program))
    assert compile_ahead.start() is None
    assert spawns == []


def test_does_not_start_in_a_frozen_application(spawns, monkeypatch):
    # PyInstaller and the like: sys.executable is the application itself (numba caches
    # there too, keyed on the executable)
    monkeypatch.setattr(sys, "frozen", True, raising=False)
    assert compile_ahead.start() is None
    assert spawns == []


@pytest.mark.parametrize("name", ["python", "python3", "python3.11", "python3.13t",
                                  "python.exe", "pythonw.exe", "Python"])
def test_starts_with_a_python_executable_of_any_usual_name(spawns, monkeypatch, tmp_path,
                                                           name):
    program = tmp_path / name
    program.write_text("")
    monkeypatch.setattr(sys, "executable", str(program))
    assert compile_ahead.start() is not None
    assert spawns[0][0][0] == str(program)


def test_a_thread_that_cannot_start_costs_no_error_and_no_zombie(spawns, monkeypatch,
                                                                 one_record_signature):
    # "can't start new thread" (a thread limit; Python >= 3.12 at interpreter shutdown)
    # must not come out of numba's compile of fit_bins: the optimisation is dropped and
    # the process it started is ended and waited for
    ended = []

    class NoThread:
        def __init__(self, *a, **kw):
            pass

        def start(self):
            raise RuntimeError("can't start new thread")

    monkeypatch.setattr(compile_ahead.threading, "Thread", NoThread)
    monkeypatch.setattr(compile_ahead.subprocess.Popen, "kill",
                        lambda self: ended.append("kill"), raising=False)
    monkeypatch.setattr(compile_ahead.subprocess.Popen, "wait",
                        lambda self, *a: ended.append("wait"), raising=False)
    data = dict(dispatcher=local_model_bins.fit_bins, args=one_record_signature)
    event.start_event("numba:compile", data=data)
    event.end_event("numba:compile", data=data)
    assert len(spawns) == 1
    assert ended == ["kill", "wait"]


def test_no_console_window_for_the_second_process_on_windows(spawns, monkeypatch):
    # a process without a console (pythonw, a notebook started from a desktop launcher)
    # would open one for the second process
    monkeypatch.setattr(compile_ahead.subprocess, "CREATE_NO_WINDOW", 0x08000000,
                        raising=False)
    assert compile_ahead.start() is not None
    assert spawns[0][1]["creationflags"] & 0x08000000


def test_the_second_process_compiles_nothing_for_another_copy_of_lcmr_xr(tmp_path):
    # the copy asked for is on the path, but behind this one: the other copy's sources
    # would be compiled, whose cache entries the asking process could not use
    other = tmp_path / "lcmr_xr"
    other.mkdir()
    (other / "__init__.py").write_text("")
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"))
    path = [compile_ahead._root(), str(tmp_path), *sys.path]
    done = subprocess.run([sys.executable, "-c", compile_ahead._BOOT, str(tmp_path), *path],
                          env=env, capture_output=True, text=True, timeout=120)
    assert done.returncode == 2, done.stderr
    assert not (tmp_path / "cache").exists()


@pytest.mark.parametrize("setting, cpus", [("0", 4), ("1", 1), (None, 1)])
def test_does_not_start_when_switched_off_or_on_one_cpu(spawns, monkeypatch, setting, cpus):
    if setting is not None:
        monkeypatch.setenv(compile_ahead.SETTING, setting)
    monkeypatch.setattr(compile_ahead, "available_cpus", lambda: cpus)
    assert compile_ahead.start() is None
    assert spawns == []


def test_a_setting_other_than_0_or_1_is_refused_by_name(monkeypatch):
    monkeypatch.setenv(compile_ahead.SETTING, "off")
    with pytest.raises(ValueError, match="LCMR_XR_COMPILE_AHEAD='off' is not 0 or 1"):
        compile_ahead.enabled()


def test_starts_on_the_compile_of_the_one_record_version_only(spawns, one_record_signature):
    pooled = one_record_signature[:-2] + (types.int64,) + one_record_signature[-1:]
    for dispatcher, args in ((local_model_bins.fit_bins, pooled),
                             (local_model_bins._recurrence, one_record_signature)):
        event.start_event("numba:compile", data=dict(dispatcher=dispatcher, args=args))
        event.end_event("numba:compile", data=dict(dispatcher=dispatcher, args=args))
    assert spawns == []
    event.start_event("numba:compile", data=dict(dispatcher=local_model_bins.fit_bins,
                                                 args=one_record_signature))
    event.end_event("numba:compile", data=dict(dispatcher=local_model_bins.fit_bins,
                                               args=one_record_signature))
    assert len(spawns) == 1


@pytest.mark.parametrize("text, expected", [
    ("int64 1d readonly", types.Array(types.int64, 1, "C", readonly=True)),
    ("complex128 3d", types.Array(types.complex128, 3, "C")),
    ("bool 1d", types.Array(types.boolean, 1, "C")),
    ("bool", types.boolean), ("none", types.none), ("float64", types.float64)])
def test_type_names_read_as_numba_types(text, expected):
    assert compile_ahead.parse_type(text) == expected


def test_numba_reports_a_compile_as_the_listener_expects():
    # the listener reads numba's "numba:compile" event: its dispatcher and its argument
    # types (pool None read as types.none); the other tests fire that event themselves, so
    # this one checks numba's own event against them
    import numba

    seen = []

    class Record(event.Listener):
        def on_start(self, ev):
            seen.append(ev.data)

        def on_end(self, ev):
            pass

    @numba.njit
    def pick(a, pool, b):
        return a if pool is None else b

    record = Record()
    event.register("numba:compile", record)
    try:
        pick(1.0, None, 2.0)
        pick(1.0, 3, 2.0)
    finally:
        event.unregister("numba:compile", record)
    found = [d["args"] for d in seen if d.get("dispatcher") is pick]
    assert [compile_ahead._one_record(args) for args in found] == [True, False]


def test_the_listener_lets_any_compile_event_pass(spawns):
    # it listens to every numba compile of the process, the user's own functions' and
    # other libraries' too: an event it cannot read must not raise out of their compile
    for data in (None, {}, {"dispatcher": local_model_bins.fit_bins},
                 {"dispatcher": local_model_bins.fit_bins, "args": None}):
        event.start_event("numba:compile", data=data)
        event.end_event("numba:compile", data=data)
    assert spawns == []
