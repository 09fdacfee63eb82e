"""The data contract is written once: ``lcmr_xr.conventions`` in code, ``docs/conventions.md``
in prose, and both agree with what the functions return.  ``docs/architecture.md`` names
only modules and functions that exist.
"""

from __future__ import annotations

import importlib
import re
from pathlib import Path

import pytest

import lcmr_xr
from lcmr_xr import conventions as cv
from lcmr_xr import hdd

ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / "docs"
README = ROOT / "README.md"

# Variables only the indirect estimate has (the direct one has no lifted S side).
S_SIDE = {cv.LIFTED_S, cv.LIFTED_S + cv.STD_SUFFIX, cv.TRANSIENT_U, cv.NOISE_VARIANCE_U,
          cv.S_CONDITION, cv.S_SINGULAR, cv.S_WEAK_REL_STD}


def _constants() -> dict:
    """The contract's names: upper-case str / tuple-of-str constants of lcmr_xr.conventions."""
    return {name: value for name, value in vars(cv).items()
            if name.isupper() and isinstance(value, (str, tuple))}


@pytest.fixture(scope="module")
def small_experiment():
    return hdd.simulate(n_samples=1200, noise=True, seed=0)


def test_prose_names_every_constant_and_its_value():
    text = (DOCS / "conventions.md").read_text()
    constants = _constants()
    assert len(constants) > 30  # the module was read, not an empty namespace
    missing = [f"cv.{name}" for name in constants if f"cv.{name}" not in text]
    assert missing == [], f"docs/conventions.md does not mention {missing}"
    values = [value for value in constants.values() if isinstance(value, str)]
    absent = [value for value in values if value not in text]
    assert absent == [], f"docs/conventions.md does not name the values {absent}"


def test_grouped_names_are_the_single_names():
    assert cv.EXPERIMENT_VARIABLES == ("r", "u", "y")
    assert len(set(cv.FRF_VARIABLES)) == len(cv.FRF_VARIABLES)
    assert len(set(cv.FRF_ATTRS)) == len(cv.FRF_ATTRS)
    assert cv.LIFT_PHASE2 == "lift_phase2" and cv.INPUT2 == "input2"


def test_experiment_has_exactly_the_contract_variables(small_experiment):
    assert set(small_experiment.data_vars) == set(cv.EXPERIMENT_VARIABLES)
    assert small_experiment.attrs[cv.CONVENTIONS_ATTR] == cv.CONVENTIONS
    assert small_experiment.attrs[cv.FACTOR] == 2


def test_identify_returns_exactly_the_contract_names(small_experiment):
    indirect = lcmr_xr.identify(small_experiment, window=20)
    assert set(indirect.data_vars) == set(cv.FRF_VARIABLES)
    assert set(indirect.attrs) == set(cv.FRF_ATTRS)
    assert set(indirect.dims) == {cv.FREQUENCY, cv.SLOW_FREQUENCY, cv.OUTPUT, cv.INPUT,
                                  cv.LIFT_PHASE, cv.LIFT_PHASE2, cv.INPUT2}
    direct = lcmr_xr.identify(small_experiment, window=20, closed_loop="direct")
    assert set(direct.data_vars) == set(cv.FRF_VARIABLES) - S_SIDE
    assert set(direct.attrs) == set(cv.FRF_ATTRS)
    single = lcmr_xr.identify_single_rate(small_experiment, window=20)
    assert set(single.data_vars) == {cv.P, cv.P + cv.STD_SUFFIX, cv.P_FLAG}
    assert set(single.attrs) <= set(cv.FRF_ATTRS)


def _dotted_names(text: str) -> list[str]:
    return sorted(set(re.findall(r"`(lcmr_xr(?:\.[A-Za-z_][A-Za-z0-9_]*)*)", text)))


def _resolve(dotted: str):
    """Import the longest module prefix of ``dotted``, then getattr the rest."""
    parts = dotted.split(".")
    for cut in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:cut]))
        except ModuleNotFoundError:
            continue
        for attr in parts[cut:]:
            obj = getattr(obj, attr)
        return obj
    raise ModuleNotFoundError(dotted)


@pytest.mark.parametrize("page", ["architecture.md", "conventions.md"])
def test_docs_name_only_real_modules_and_functions(page):
    names = _dotted_names((DOCS / page).read_text())
    assert len(names) > 3
    broken = []
    for name in names:
        try:
            _resolve(name)
        except (ImportError, AttributeError):
            broken.append(name)
    assert broken == [], f"docs/{page} names {broken}, which do not exist; update the page"


def test_readme_links_the_docs_and_no_code_cites_an_outside_design_doc():
    readme = README.read_text()
    assert "docs/architecture.md" in readme and "docs/conventions.md" in readme
    stale = [str(p.relative_to(ROOT)) for p in (ROOT / "lcmr_xr").rglob("*.py")
             if "shared/conventions.md" in p.read_text()]
    assert stale == [], f"{stale} cite shared/conventions.md; cite docs/conventions.md"


@pytest.mark.parametrize("units,squared", [
    ("m", "m2"), ("V", "V2"), ("um", "um2"), ("rad", "rad2"),  # a symbol: exponent 2, as UDUNITS
    ("m2", "m4"), ("s-1", "s-2"), ("m^3", "m6"),             # an exponent doubles (not m22)
    ("m/s", "(m/s)2"), ("m s-1", "(m s-1)2"), ("1e-3 m", "(1e-3 m)2"),  # else parenthesised
    ("1", "1"), ("", "1"),
])
def test_squared_units(units, squared):
    assert cv.squared_units(units) == squared


def test_noise_variance_units_are_the_signals_units_squared():
    """The noise variances' units read (m)2 for an output in m (every unit was
    parenthesised); now UDUNITS' own spelling: m2, and (m/s)2 where parentheses are needed.
    Residual (identify) and period-spread (pooled) variances, outputs and lifted inputs."""
    exp = hdd.simulate(n_samples=1200, periods=3, seed=0, noise=False)
    exp["u"].attrs["units"] = "m/s"
    frf = lcmr_xr.identify(exp, window=12, degrees=(2, 2, 2))
    assert frf[cv.NOISE_VARIANCE_Y].attrs["units"] == "m2"
    assert frf[cv.PERIOD_NOISE_VARIANCE_Y].attrs["units"] == "m2"
    assert frf[cv.NOISE_VARIANCE_U].attrs["units"] == "(m/s)2"
    assert frf[cv.PERIOD_NOISE_VARIANCE_U].attrs["units"] == "(m/s)2"
    exp["u"].attrs["units"] = "1"
    frf = lcmr_xr.identify(exp.isel(period=0), window=12, degrees=(2, 2, 2))
    assert frf[cv.NOISE_VARIANCE_U].attrs["units"] == "1" and frf[cv.NOISE_VARIANCE_Y].attrs["units"] == "m2"
    stacked = lcmr_xr.identify(exp.isel(period=0), window=12, degrees=(2, 2, 2), stacked=True)
    assert stacked["noise_variance"].attrs["units"] == "1 (u rows), m2 (y rows)"


def test_one_figure_for_the_cost_of_iv_on_one_record():
    """The README (1.2-1.9x), lcmr_xr.settings (1.8-2.4x), identify's docstring (about
    twice) and docs/uncertainty.md (1.88x) each gave their own cost of IV on one record;
    they give the one measured in docs/uncertainty.md (benchmarks/accuracy.py --cost)."""
    import lcmr_xr.settings

    def one(pattern, text, where):
        found = re.findall(pattern, " ".join(text.split()))
        assert len(found) == 1, (where, found)
        return found[0]

    figure = r"(\d\.\d+-\d\.\d+x)"
    measured = one(r"Cost of IV against least squares, one record .*?: window 30 " + figure,
                   (DOCS / "uncertainty.md").read_text(), "uncertainty.md")
    assert one(r"IV changes the result by a few per cent at " + figure + " the CPU time, window 30",
               README.read_text(), "README") == measured
    assert one(r"costs " + figure + " the CPU time at window 30",
               Path(lcmr_xr.settings.__file__).read_text().replace("#:", ""), "settings") == measured
    assert one(r"at " + figure + " the CPU time at window 30",
               lcmr_xr.identify.__doc__, "identify") == measured
