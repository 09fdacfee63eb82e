"""Estimator settings: the one table of choices and the one validator of them.

Every entry point (:func:`lcmr_xr.identify`, :func:`lcmr_xr.identify_single_rate`,
:func:`lcmr_xr.scaleout.sweep`, ``lcmr-xr identify`` and ``lcmr-xr sweep``) passes its
settings through :func:`estimator_settings` before it touches the data, so a bad value gets
the same message everywhere, also on lazy (dask) input where nothing would otherwise run
until compute time.  Adding a local-model method means one row in :data:`METHODS` (and, if
it is not a degrees choice of the local model, one kernel call).

One rule for whole numbers (:func:`as_integer`, used by every integer argument of the
library's entry points: ``window``, ``frequency_chunks``, ``transient_periods``, the
degrees, ``periods``, ``experiments_per_task``, ``n_samples``, ...): ints, numpy ints and
integral floats (``30.0``) are accepted; a fraction (``30.5``) is a ``ValueError`` (never
rounded); a bool, a string or another non-number is a ``TypeError`` naming the argument.
The degrees are also text (``"3-3-3"``, so ``("3", 3, 3)`` is read too), and any malformed
degrees (``(True, 3, 3)``, ``(2.5, 3, 3)``) are one ``ValueError`` (:func:`parse_degrees`);
on the command line the same rule reads ``--samples 3600.0`` as 3600
(:func:`lcmr_xr._cli_support.integer_argument`).

A leaf module (it imports only numpy) like :mod:`lcmr_xr.conventions`.  The kernels do not
import it (they import nothing outside :mod:`lcmr_xr.kernels`); the closed-loop variants
they implement, ``lcmr_xr.kernels.identification.CLOSED_LOOP_METHODS``, are kept equal to
:data:`CLOSED_LOOP` by a test.
"""

from __future__ import annotations

import numbers
import re
from typing import NamedTuple

import numpy as np

__all__ = [
    "METHODS", "CLOSED_LOOP", "ERRORS", "EstimatorSettings", "estimator_settings",
    "parse_degrees", "degrees_label", "degrees_arguments", "as_integer", "as_bool", "as_choice",
    "recorded_factor",
    "check_window_fits", "AUTO_WINDOW", "DEFAULT_WINDOW", "as_window", "window_argument",
    "auto_window_range", "DENOMINATOR", "DEFAULT_DENOMINATOR", "POOLED_DEFAULT_DENOMINATOR",
    "NO_DENOMINATOR",
    "as_denominator",
]


class Method(NamedTuple):
    """One local-model method: what it is, its default degrees, whether ``Rd`` is free."""

    description: str
    default_degrees: tuple[int, int, int]
    has_denominator: bool


#: Local-model methods.  The kernel is one: the LPM is the LRM with denominator degree 0.
METHODS = {
    "lrm": Method("local rational model", (3, 3, 3), True),
    "lpm": Method("local polynomial model (denominator degree Rd = 0)", (3, 3, 0), False),
}

#: Closed-loop variants of the estimator (``closed_loop=``).
CLOSED_LOOP = {
    "indirect": "[S; PS_1] from the lifted excitation r, then P_1 = PS_1 S^-1 (unbiased under feedback)",
    "direct": "local model from the lifted measured input u to y (biased under feedback)",
}

#: How the local rational model's denominator is estimated (``denominator=``).  Only a
#: model with a denominator (``Rd > 0``) has the choice; ``None`` is the default below.
DENOMINATOR = {
    "ls": "least squares, the paper's LRM: the noise on Z among the denominator's regressors "
          "biases G (errors-in-variables)",
    "iv": "instrumental variables: the denominator's regressors are instrumented by a "
          "prediction of Z from a first fit (docs/uncertainty.md)",
}
#: ``denominator=None`` means this for a model with a denominator (``Rd > 0``) fitted to
#: one record.  Measured on the HDD benchmark (docs/uncertainty.md, "Instrumental
#: variables"): on one record IV changes the error and the coverage by a few per cent and
#: costs 1.33-1.41x the CPU time at window 30 (1.11-1.18x with ``window="auto"``;
#: ``benchmarks/accuracy.py --cost``), so least squares stays the default there.
DEFAULT_DENOMINATOR = "ls"
#: ... and this for experiments pooled in one local model (``combine="experiment"`` with
#: different excitations and a local window), where least squares' noise-induced bias,
#: which pooling does not shrink, dominates the error: IV lowers the error 1.5-1.8x at
#: 0.5-25 kHz and brings the pooled band's coverage from 0.69-0.86 to 0.90-0.98 at
#: 0.5-50 kHz (below 500 Hz, where neither keeps its promise, from 0.82-0.89 to 0.77-0.78).
POOLED_DEFAULT_DENOMINATOR = "iv"
#: What the result records when no denominator is fitted (``Rd = 0``: the LPM; window 0).
NO_DENOMINATOR = "none"

#: What to do with a non-invertible estimated S (``errors=``).
ERRORS = {
    "raise": "raise a ValueError naming the bins",
    "ignore": "return NaN with the flag s_singular there",
}

#: ``window=AUTO_WINDOW``: the half-width is chosen per slow bin (lcmr_xr.kernels.adaptive).
AUTO_WINDOW = "auto"
#: The default ``window`` of :func:`lcmr_xr.identify` and of the ``identify``/``demo``
#: command lines (the one place it is set).  Sweeps compare fixed windows (default 30).
DEFAULT_WINDOW = AUTO_WINDOW

#: The degrees syntax of the command lines and sweep labels: ``Rn-Rm-Rd``.
DEGREES_SYNTAX = "Rn-Rm-Rd"


class EstimatorSettings(NamedTuple):
    """Validated settings of a local-model FRF estimate (see :func:`estimator_settings`)."""

    method: str
    degrees: tuple[int, int, int]
    window: int | str  # a half-width, or AUTO_WINDOW
    closed_loop: str
    covariance: bool
    errors: str
    frequency_chunks: int | None
    # "ls", "iv", or NO_DENOMINATOR when the model has none (Rd = 0); last, with a
    # default, so that positional constructions of the older fields keep working
    denominator: str = DEFAULT_DENOMINATOR


def _either(choices) -> str:
    names = [repr(c) for c in choices]
    return names[0] if len(names) == 1 else ", ".join(names[:-1]) + " or " + names[-1]


def as_choice(value, name: str, choices) -> str:
    """``value`` if it is one of the str ``choices``; else a message listing them.

    Examples
    --------
    >>> as_choice("lpm", "method", METHODS)
    'lpm'
    """
    if not isinstance(value, str) or value not in choices:
        kind = "" if isinstance(value, str) else f" (a {type(value).__name__})"
        raise ValueError(f"{name} must be {_either(choices)}, got {value!r}{kind}.")
    return value


def as_bool(value, name: str) -> bool:
    """``value`` as a bool; only ``True``/``False`` (also numpy's) are accepted.

    Why strict: ``bool("no")`` is ``True``, so a string would silently mean the opposite.

    Examples
    --------
    >>> as_bool(np.True_, "covariance")
    True
    """
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    raise TypeError(f"{name} must be True or False, got {value!r} ({type(value).__name__}); "
                    f"pass {name}=True or {name}=False.")


def as_integer(value, name: str, *, minimum: int | None = None, example=None) -> int:
    """``value`` as an int: ints, numpy ints and integral floats (``30.0``) are accepted.

    A 0-d array (numpy or xarray) is read as the number it holds.  A fractional number
    (``30.5``, a ``ValueError``: never rounded), a bool or a non-number (a ``TypeError``,
    naming ``name``) is refused.

    Examples
    --------
    >>> as_integer(np.int64(30), "window"), as_integer(30.0, "window")
    (30, 30)
    """
    remedy = f"; pass e.g. {name}={example}" if example is not None else f"; pass {name} >= {minimum}"
    example = value if example is None else example
    if isinstance(value, np.ndarray) and value.ndim == 0 or (
            type(value).__name__ == "DataArray" and getattr(value, "ndim", None) == 0):
        value = value.item()  # one number (a 0-d array, e.g. a sweep's best window .values)
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
        raise TypeError(f"{name} must be an integer, got {value!r} ({type(value).__name__}); "
                        f"pass e.g. {name}={example}.")
    if isinstance(value, numbers.Integral):
        out = int(value)
    else:
        if not np.isfinite(value) or float(value) != int(value):
            raise ValueError(f"{name} must be an integer, got {value!r}; it is not rounded: pass "
                             f"{name}={int(np.floor(value)) if np.isfinite(value) else example} "
                             f"or another whole number.")
        out = int(value)
    if minimum is not None and out < minimum:
        raise ValueError(f"{name} must be >= {minimum}, got {out}{remedy}.")
    return out


def recorded_factor(value) -> int | None:
    """A recorded multirate factor as an int, or None if ``value`` is not one.

    The one reader of a factor stored with the data (an experiment's attribute
    ``factor``, a ``lift_phase`` coordinate's ``lift_factor``): one whole number >= 1,
    also as a whole float (``2.0``) or a one-element array (``array([2])``, ``[[2.0]]``),
    as a NetCDF or MATLAB file may give an attribute back.  Text, a bool, several
    numbers, a fraction, NaN or inf and numbers below 1 are not read (None), for the
    caller to refuse in its own words: a stored value is data, not an argument, so it is
    never guessed.

    Parameters
    ----------
    value : object
        The stored attribute.

    Returns
    -------
    int or None
        The factor, or None if ``value`` is not one whole number >= 1.

    Examples
    --------
    >>> recorded_factor(np.array([[2.0]])), recorded_factor("2"), recorded_factor(2.5)
    (2, None, None)
    """
    try:
        array = np.asarray(value)
    except (ValueError, TypeError):  # ragged ([1, [2]]): numpy's own error, not the caller's words
        return None
    if array.size != 1 or array.dtype.kind not in "iuf":
        return None
    number = array.item()
    if not np.isfinite(number) or number < 1 or number != int(number):
        return None
    return int(number)


def parse_degrees(value, method: str | None = None, *,
                  no_transient: bool = False) -> tuple[int, int, int]:
    """``(Rn, Rm, Rd)`` from ``"Rn-Rm-Rd"`` (or ``"Rn,Rm,Rd"``, ``"Rn Rm Rd"``) or integers.

    Parameters
    ----------
    value : str or sequence of int
        Numerator, transient and denominator degrees of the local model.  With
        ``method="lpm"`` the pair ``(Rn, Rm)`` is accepted (``Rd = 0``), and ``Rd`` other than
        0 is refused: the local polynomial model has no denominator.
    method : {"lrm", "lpm"}, optional
        Apply that method's rule for ``Rd``; ``None``: any three non-negative integers.
    no_transient : bool, default False
        Also accept ``Rm = -1`` (no transient term), given as integers (e.g. ``(3, -1, 3)``):
        only for steady-state periodic data (:func:`lcmr_xr.identify` checks the data).

    Returns
    -------
    tuple of int

    Raises
    ------
    ValueError
        Not two or three non-negative integers, or ``Rd != 0`` with ``method="lpm"``.

    Examples
    --------
    >>> parse_degrees("3-2-1"), parse_degrees((2, 2, 0)), parse_degrees("3,3", "lpm")
    ((3, 2, 1), (2, 2, 0), (3, 3, 0))
    """
    if isinstance(value, str):
        parts = [p for p in re.split(r"[-,\s]+", value.strip()) if p]
    elif isinstance(value, (numbers.Number, np.generic)) or not hasattr(value, "__iter__"):
        parts = None
    else:
        parts = list(value)
    out = None
    if parts is not None:
        try:
            out = tuple(as_integer(int(p) if isinstance(p, str) else p, "degree", minimum=0)
                        for p in parts)
        except (TypeError, ValueError):
            out = None
    lpm_pair = method is not None and not METHODS[method].has_denominator and out is not None \
        and len(out) == 2
    if lpm_pair:
        out = out + (0,)
    if out is None and no_transient and parts is not None and len(parts) in (2, 3) \
            and not isinstance(value, str):
        try:  # Rm = -1: the transient term left out (periodic data); the others >= 0
            out = tuple(as_integer(p, "degree", minimum=-1 if i == 1 else 0)
                        for i, p in enumerate(parts))
        except (TypeError, ValueError):
            out = None
        if out is not None and len(out) == 2:
            out = out + (0,) if lpm_pair_ok(method) else None
    if out is None or len(out) != 3:
        pair = " (or the pair Rn-Rm for method='lpm')" if method != "lrm" else ""
        raise ValueError(
            f"degrees {value!r} is not three non-negative integers {DEGREES_SYNTAX} (numerator, "
            f"transient, denominator){pair}; write e.g. '3-3-3' or (3, 3, 3)."
        )
    if method is not None and not METHODS[method].has_denominator and out[2] != 0:
        raise ValueError(
            f"method={method!r} is the {METHODS[method].description}; got degrees={out}. "
            f"Pass degrees=({out[0]}, {out[1]}, 0) (label '{out[0]}-{out[1]}-0'), or "
            f"method='lrm' for a denominator of degree {out[2]}."
        )
    return out


def degrees_label(degrees) -> str:
    """The ``"Rn-Rm-Rd"`` label of a degrees triple (the ``degrees`` coordinate of a sweep).

    Parameters
    ----------
    degrees : tuple of int or str
        ``(Rn, Rm, Rd)`` or a label such as ``"3-3-3"`` (anything :func:`parse_degrees`
        accepts).

    Returns
    -------
    str
        ``"Rn-Rm-Rd"``.

    Examples
    --------
    >>> degrees_label((3, 3, 0))
    '3-3-0'
    """
    return "-".join(str(d) for d in parse_degrees(degrees))


def as_window(value) -> int | str:
    """``window``: a half-width >= 1 (whole numbers only) or ``"auto"``.

    Examples
    --------
    >>> as_window("auto"), as_window(30.0)
    ('auto', 30)
    """
    if isinstance(value, str):
        if value == AUTO_WINDOW:
            return value
        raise TypeError(f"window must be an integer or {AUTO_WINDOW!r}, got {value!r} (a str); "
                        f"pass e.g. window=30 or window={AUTO_WINDOW!r}.")
    return as_integer(value, "window", minimum=1, example=30)


def window_argument(text: str):
    """A command line's ``--window`` token, for :func:`estimator_settings` to check.

    ``"auto"`` stays a string, numbers become numbers (``30.5`` too: the validator refuses
    it with its own words, never rounded); anything else is passed on as text and refused
    there.

    Examples
    --------
    >>> window_argument("auto"), window_argument("20"), window_argument("30.5")
    ('auto', 20, 30.5)
    """
    text = str(text).strip()
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text


def as_denominator(value, degrees) -> str:
    """``denominator`` for a model of ``degrees``: ``"ls"``, ``"iv"`` or ``"none"`` (Rd = 0).

    ``None`` is :data:`DEFAULT_DENOMINATOR` where the model has a denominator (the caller
    that pools experiments in one local model uses :data:`POOLED_DEFAULT_DENOMINATOR`
    instead) and ``"none"`` where it has not; ``"ls"`` is accepted for a model without one (least
    squares is what is done), ``"iv"`` is refused there (there is nothing to instrument).

    Examples
    --------
    >>> as_denominator(None, (3, 3, 3)), as_denominator("iv", (3, 3, 3)), as_denominator(None, (3, 3, 0))
    ('ls', 'iv', 'none')
    """
    has_denominator = tuple(degrees)[2] > 0
    if value is None:
        return DEFAULT_DENOMINATOR if has_denominator else NO_DENOMINATOR
    value = as_choice(value, "denominator", DENOMINATOR)
    if not has_denominator:
        if value == "iv":
            raise ValueError(
                f"denominator='iv' instruments the denominator of the local rational model, but "
                f"degrees {tuple(degrees)} have none (Rd = 0: the local polynomial model, whose "
                f"least squares has no noisy regressors). Drop denominator (or pass "
                f"denominator='ls'), or use method='lrm' with Rd > 0 (e.g. degrees=(3, 3, 3)).")
        return NO_DENOMINATOR
    return value


def lpm_pair_ok(method) -> bool:
    """Whether ``method`` takes the degrees pair ``(Rn, Rm)`` (no denominator)."""
    return method is not None and not METHODS[method].has_denominator


def estimator_settings(*, method="lrm", window=DEFAULT_WINDOW, degrees=None,
                       closed_loop="indirect",
                       covariance=True, errors="raise", frequency_chunks=None,
                       no_transient: bool = False, denominator=None) -> EstimatorSettings:
    """Check and normalise every setting of a local-model estimate, before any data is read.

    Parameters
    ----------
    method, window, degrees, closed_loop, covariance, errors, frequency_chunks
        As in :func:`lcmr_xr.identify`.  ``degrees=None`` is the method's default
        (:data:`METHODS`); ``window`` a half-width or ``"auto"`` (default
        :data:`DEFAULT_WINDOW`), which needs ``covariance=True``; its ``frequency_chunks``
        (any value is accepted here) is checked by :func:`lcmr_xr.identify` once the
        candidate windows are known: at least the widest plus the halo of any instruments'
        first fit (on the HDD 60 with the default least-squares LRM of one record, whose
        Hausman comparison fits instruments from the widest window;
        42 with ``denominator="iv"``; 30 for the LPM).
    no_transient : bool, default False
        Accept ``Rm = -1`` in ``degrees`` (see :func:`parse_degrees`); the caller checks that
        the data are steady-state periodic.
    denominator : {None, "ls", "iv"}, optional
        How the denominator is estimated (:data:`DENOMINATOR`; :func:`as_denominator`):
        ``None`` is :data:`DEFAULT_DENOMINATOR` with a denominator, ``"none"`` without.

    Returns
    -------
    EstimatorSettings
        Plain ints, bools and strs; ``degrees`` a triple.

    Raises
    ------
    TypeError
        A value of the wrong type (``covariance="no"``, ``window="30"``).
    ValueError
        A value out of range or not among the choices (``window=30.5``, ``method="arx"``,
        ``degrees=(3, 3, 3)`` with ``method="lpm"``, ``frequency_chunks < window``,
        ``denominator="iv"`` without a denominator).

    Examples
    --------
    >>> estimator_settings(method="lpm", window=20.0).degrees
    (3, 3, 0)
    """
    method = as_choice(method, "method", METHODS)
    degrees = METHODS[method].default_degrees if degrees is None else \
        parse_degrees(degrees, method, no_transient=no_transient)
    window = as_window(window)
    closed_loop = as_choice(closed_loop, "closed_loop", CLOSED_LOOP)
    covariance = as_bool(covariance, "covariance")
    errors = as_choice(errors, "errors", ERRORS)
    if frequency_chunks is not None:
        frequency_chunks = as_integer(frequency_chunks, "frequency_chunks", minimum=1, example=64)
    if window == AUTO_WINDOW:
        if not covariance:
            raise ValueError("window='auto' chooses the window from the estimates' covariances; "
                             "pass covariance=True, or an integer window (e.g. window=30) with "
                             "covariance=False.")
    elif frequency_chunks is not None and frequency_chunks < window:
        raise ValueError(
            f"frequency_chunks={frequency_chunks} is smaller than the halo the local window "
            f"needs (window={window} bins on each side); use frequency_chunks >= {window}."
        )
    denominator = as_denominator(denominator, degrees)
    return EstimatorSettings(method, degrees, window, closed_loop, covariance, errors,
                             frequency_chunks, denominator)


def auto_window_range(degrees, n_excitation: int, n_bins: int) -> tuple[int, int]:
    """Smallest and largest half-width ``window="auto"`` may choose from.

    The smallest leaves two degrees of freedom per row (``2 n + 1 >= p + 2``, so the
    small-sample factor of the band stays finite); the largest fits the spectrum.
    """
    from lcmr_xr.kernels.local_models import parameters_per_row

    p = parameters_per_row(n_excitation, tuple(degrees))
    return p // 2 + 1, (n_bins - 1) // 2


def check_window_fits(window, degrees, n_excitation: int, n_bins: int) -> None:
    """Refuse a window with too few bins for the local model, or wider than the spectrum.

    Parameters
    ----------
    window : int or "auto"
        Half-width ``n`` (``2 n + 1`` bins); ``"auto"``: the smallest candidate must fit.
    degrees : (int, int, int)
        ``(Rn, Rm, Rd)``.
    n_excitation : int
        Excitation channels of the local model (``F nu`` lifted, ``nu`` single-rate).
    n_bins : int
        Slow DFT bins ``M`` of the spectrum.

    Examples
    --------
    >>> check_window_fits(30, (3, 3, 3), 4, 1800)  # the paper's HDD settings
    """
    from lcmr_xr.kernels.local_models import parameters_per_row

    p = parameters_per_row(n_excitation, degrees)
    n_min = (p + 1) // 2
    if 2 * n_min + 1 > n_bins:  # no window fits: a shorter window cannot help, only more data
        raise ValueError(
            f"the experiment is too short for the local model: it has M = {n_bins} slow samples "
            f"(slow DFT bins), but degrees {tuple(degrees)} with {n_excitation} excitation "
            f"channels need {p} parameters per row, i.e. window >= {n_min} and 2n+1 = "
            f"{2 * n_min + 1} bins. Record at least {2 * n_min + 1} slow samples (N >= "
            f"{2 * n_min + 1} x factor fast samples), or lower the degrees."
        )
    if window == AUTO_WINDOW:
        lo, hi = auto_window_range(degrees, n_excitation, n_bins)
        if lo > hi:
            raise ValueError(
                f"the experiment is too short for window='auto': it has M = {n_bins} slow bins, "
                f"but degrees {tuple(degrees)} with {n_excitation} excitation channels need "
                f"{p} parameters per row, and the smallest candidate window ({2 * lo + 1} bins) "
                f"leaves two degrees of freedom for the band. Pass window={(p + 1) // 2} or "
                f"more, lower the degrees, or record a longer experiment."
            )
        return
    if 2 * window + 1 <= p:  # at least one degree of freedom is left for the noise estimate
        raise ValueError(
            f"too few bins for the local model: window={window} gives 2n+1 = {2 * window + 1} bins "
            f"per row but degrees {tuple(degrees)} with {n_excitation} excitation channels need "
            f"{p} parameters per row and at least one more bin for the noise estimate. "
            f"Use window >= {(p + 1) // 2} (or lower degrees)."
        )
    if 2 * window + 1 > n_bins:
        raise ValueError(
            f"the local window (2n+1 = {2 * window + 1} bins for window={window}) is wider than the "
            f"spectrum ({n_bins} slow bins). Use window <= {(n_bins - 1) // 2} or a longer experiment."
        )


def degrees_arguments(tokens) -> list[str]:
    """The degrees settings of a command line's ``--degrees`` tokens (syntax ``RN-RM-RD``).

    Each token is one setting ``RN-RM-RD`` (or ``RN,RM,RD``); bare integers ``RN RM RD``
    are read as one setting too (the older ``lcmr-xr identify`` spelling).  The settings
    are parsed with the method's rule by :func:`estimator_settings` (or the sweep).

    Examples
    --------
    >>> degrees_arguments(["3-3-3", "2,2,0"]), degrees_arguments(["2", "2", "2"])
    (['3-3-3', '2,2,0'], ['2-2-2'])
    """
    tokens = [str(t).strip() for t in tokens]
    if tokens and all(t.isdigit() for t in tokens):
        return ["-".join(tokens)]
    return tokens
