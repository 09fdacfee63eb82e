"""Every public function and class of lcmr_xr has a numpydoc docstring matching its signature.

Public means: listed in the module's ``__all__`` when it has one, otherwise a name not
starting with ``_`` that is defined in the module (or its subpackage), not imported from
elsewhere.  For the listed subpackages (not the top-level ``lcmr_xr``, whose API is its
``__all__``) every public submodule is checked too, so a function is covered even before
the package re-exports it.  Modules of the list that do not exist yet are skipped;
modules in ``REQUIRED_MODULES`` must exist.
"""

from __future__ import annotations

import importlib
import importlib.util
import inspect
import pkgutil
import warnings

import pytest
from numpydoc.docscrape import ClassDoc, FunctionDoc

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

_IMPLICIT = {"self", "cls"}


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


def _documented_names(section) -> list[str]:
    """Names of a numpydoc Parameters/Attributes section; ``"x, y : float"`` gives both."""
    names = []
    for parameter in section:
        names += [n.strip().lstrip("*") for n in parameter.name.split(",") if n.strip()]
    return names


def _docstring_problems(obj) -> list[str]:
    """What is wrong with the docstring of ``obj``; an empty list when nothing."""
    if not inspect.getdoc(obj):
        return ["has no docstring"]
    with warnings.catch_warnings():
        # numpydoc warns about unknown sections; that is a malformed docstring here.
        warnings.simplefilter("error")
        try:
            if inspect.isclass(obj):
                doc = ClassDoc(obj, config={"show_class_members": False})
            else:
                doc = FunctionDoc(obj)
        except Exception as exc:  # noqa: BLE001 - any parse failure is the finding
            return [f"docstring does not parse as numpydoc: {exc}"]
    problems = []
    if not "".join(doc["Summary"]).strip():
        problems.append("docstring has no summary line")
    try:
        signature = inspect.signature(obj)
    except (TypeError, ValueError):  # builtins without a signature: nothing to compare
        return problems
    parameters = {
        name: p for name, p in signature.parameters.items() if name not in _IMPLICIT
    }
    documented = _documented_names(doc["Parameters"])
    # A class (a dataclass) may document its fields as Attributes instead.
    also = _documented_names(doc["Attributes"]) if inspect.isclass(obj) else []
    for name in parameters:
        if name not in documented and name not in also:
            problems.append(f"parameter {name!r} is not documented")
    takes_var_keyword = any(p.kind is inspect.Parameter.VAR_KEYWORD for p in parameters.values())
    for name in documented:
        # With **kwargs the accepted keywords are documented by name.
        if name not in parameters and not takes_var_keyword:
            problems.append(f"documents parameter {name!r} that is not in the signature")
    return problems


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


@pytest.mark.parametrize(
    "obj, expected",
    [
        (_good, []),
        (_Documented, []),
        (_MethodSelf, []),
        (_undocumented, ["parameter 'b' is not documented"]),
        (_stale, ["documents parameter 'gone' that is not in the signature"]),
        (_no_summary, ["docstring has no summary line"]),
        (_no_docstring, ["has no docstring"]),
    ],
)
def test_checker_finds_problems(obj, expected):
    assert _docstring_problems(obj) == expected


def test_checker_rejects_misspelled_section():
    problems = _docstring_problems(_bad_section)
    assert len(problems) == 1 and "does not parse" in problems[0]
