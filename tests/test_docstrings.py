"""Every public function and class of lcmr_xr passes numpydoc's own validation.

The checks are those of ``[tool.numpydoc_validation]`` in ``pyproject.toml`` (read with
numpydoc's own parser, the one ``numpydoc lint`` uses), applied with
:func:`numpydoc.validate.validate`.  Public means: listed in the module's ``__all__`` when
it has one, otherwise a name not starting with ``_`` that is defined in the module (or its
subpackage), not imported from elsewhere.  For the listed subpackages (not the top-level
``lcmr_xr``, whose API is its ``__all__``) every public submodule is checked too, so a
function is covered even before the package re-exports it.  Modules of the list that do
not exist yet are skipped; modules in ``REQUIRED_MODULES`` must exist.
"""

from __future__ import annotations

import dataclasses
import importlib
import importlib.util
import inspect
import pkgutil
import warnings
from pathlib import Path

import pytest
from numpydoc.docscrape import ClassDoc
from numpydoc.hooks.validate_docstrings import parse_config
from numpydoc.validate import get_doc_object, get_validation_checks, validate

ROOT = Path(__file__).resolve().parent.parent
CONFIG = parse_config(ROOT)
CHECKS = get_validation_checks(CONFIG["checks"])
EXCLUDE = CONFIG["exclude"]  # numpydoc compiles the patterns into one regex (or None)

# The lead extends this list as modules land; each must import.
REQUIRED_MODULES = [
    "lcmr_xr",
    "lcmr_xr.plot",
    "lcmr_xr.hdd",
    "lcmr_xr.transforms",
    "lcmr_xr.excitation",
    "lcmr_xr.experiment",
    "lcmr_xr.io",
    "lcmr_xr.identification",
    "lcmr_xr.simulation",
    "lcmr_xr.scaleout",
]

CHECKED_MODULES = [
    "lcmr_xr",
    "lcmr_xr.plot",
    "lcmr_xr.hdd",
    "lcmr_xr.transforms",
    "lcmr_xr.excitation",
    "lcmr_xr.experiment",
    "lcmr_xr.io",
    "lcmr_xr.identification",
    "lcmr_xr.simulation",
    "lcmr_xr.scaleout",
]


def _module_exists(name: str) -> bool:
    try:
        return importlib.util.find_spec(name) is not None
    except ModuleNotFoundError:  # a parent package is missing
        return False


def _public_callables(module) -> dict:
    """``{qualified name: object}`` of the module's public functions and classes."""
    if hasattr(module, "__all__"):
        names = list(module.__all__)
    else:
        # Without __all__, only what the module defines itself: not numpy & co.
        names = [
            n for n, obj in vars(module).items()
            if not n.startswith("_")
            and (getattr(obj, "__module__", None) or "").startswith(module.__name__)
        ]
    found = {}
    for name in names:
        obj = getattr(module, name)
        if inspect.isfunction(obj) or inspect.isclass(obj):
            found[f"{module.__name__}.{name}"] = obj
    return found


def _docstring_problems(obj) -> list[str]:
    """numpydoc's findings on the docstring of ``obj`` for the configured checks, as text."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # numpydoc warns and reports (GL06): the report counts
        errors = [(code, message) for code, message in validate(get_doc_object(obj))["errors"]
                  if code in CHECKS]
    if dataclasses.is_dataclass(obj):
        # A dataclass's fields are its constructor's parameters; a result object documents
        # them as Attributes, which counts as documented.
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            attributes = {a.name for a in ClassDoc(obj, config={"show_class_members": False})["Attributes"]}
        fields = {f.name for f in dataclasses.fields(obj)}
        if fields <= attributes:
            errors = [(code, message) for code, message in errors if code != "PR01"]
    return [f"{code} {message}" for code, message in errors]


def test_required_modules_import():
    missing = []
    for name in REQUIRED_MODULES:
        try:
            importlib.import_module(name)
        except ImportError as exc:
            missing.append(f"{name}: {exc}")
    assert not missing, "required modules do not import:\n" + "\n".join(missing)


def _public_submodules(package) -> list[str]:
    """Names of the public (no ``_`` component) modules below ``package``."""
    if not hasattr(package, "__path__"):
        return []
    return sorted(
        info.name
        for info in pkgutil.walk_packages(package.__path__, prefix=package.__name__ + ".")
        if not any(part.startswith("_") for part in info.name.split("."))
    )


@pytest.mark.parametrize("module_name", CHECKED_MODULES)
def test_public_docstrings(module_name):
    if not _module_exists(module_name):
        pytest.skip(f"{module_name} does not exist yet")
    module = importlib.import_module(module_name)  # an existing module that fails to import fails
    callables = _public_callables(module)
    if module_name != "lcmr_xr":
        for name in _public_submodules(module):
            callables.update(_public_callables(importlib.import_module(name)))
    report, seen = [], set()
    for qualified, obj in sorted(callables.items()):
        if id(obj) in seen:  # re-exported by the package: checked once
            continue
        seen.add(id(obj))
        if EXCLUDE is not None and EXCLUDE.search(f"{obj.__module__}.{obj.__qualname__}"):
            continue
        report += [f"{qualified}: {problem}" for problem in _docstring_problems(obj)]
    assert not report, "docstring problems:\n" + "\n".join(report)


def test_public_names_of_plot_are_found():
    """The discovery itself works: it sees the plot API (so a pass above means something)."""
    found = _public_callables(importlib.import_module("lcmr_xr.plot"))
    assert {"lcmr_xr.plot.bode", "lcmr_xr.plot.save_figure", "lcmr_xr.plot.BodePlot"} <= set(found)


# The checker must catch what it is for: examples of bad and good docstrings.


def _good(a, b=1, *, c=None):
    """Add things.

    Parameters
    ----------
    a : int
        First.
    b, c : int, optional
        Others.
    """


def _undocumented(a, b):
    """Add things.

    Parameters
    ----------
    a : int
        First.
    """


def _stale(a):
    """Add things.

    Parameters
    ----------
    a : int
        First.
    gone : int
        Removed long ago.
    """


def _no_summary(a):
    """
    Parameters
    ----------
    a : int
        First.
    """


def _no_docstring(a):
    pass


def _bad_section(a):
    """Add things.

    Paramters
    ---------
    a : int
        First.
    """


class _Documented:
    """A result.

    Attributes
    ----------
    x : float
        A value.
    """

    def __init__(self, x):
        self.x = x


class _MethodSelf:
    """A thing.

    Parameters
    ----------
    y : int
        A value.
    """

    def __init__(self, y):
        self.y = y


@dataclasses.dataclass
class _Result:
    """A result.

    Attributes
    ----------
    x : float
        A value.
    """

    x: float


@dataclasses.dataclass
class _ResultMissingField:
    """A result.

    Attributes
    ----------
    x : float
        A value.
    """

    x: float
    y: float


@pytest.mark.parametrize(
    "obj, expected",
    [
        (_good, []),
        # a plain class documents its constructor's parameters under Parameters
        (_Documented, ["PR01 Parameters {'x'} not documented"]),
        (_MethodSelf, []),
        (_Result, []),
        (_undocumented, ["PR01 Parameters {'b'} not documented"]),
        (_stale, ["PR02 Unknown parameters {'gone'}"]),
        (_no_summary, ["SS01"]),
        (_no_docstring, ["GL08 The object does not have a docstring"]),
        (_ResultMissingField, ["PR01"]),
    ],
)
def test_checker_finds_problems(obj, expected):
    problems = _docstring_problems(obj)
    assert len(problems) == len(expected)
    assert all(p.startswith(e) for p, e in zip(problems, expected)), problems


def test_checker_rejects_misspelled_section():
    problems = _docstring_problems(_bad_section)
    assert any(p.startswith("GL06") and "Paramters" in p for p in problems), problems


def test_configured_checks_cover_the_promises():
    """The pyproject table asks for what this suite promises, and numpydoc knows every code."""
    assert {"GL08", "SS01", "PR01", "PR02", "GL06"} <= CHECKS
    assert EXCLUDE is not None and EXCLUDE.search("lcmr_xr.plot.bode._phase_deg")
    assert not EXCLUDE.search("lcmr_xr.plot.bode.bode")
