"""Names of the FRF dataset and the ``long_name [units]`` labels of the plots.

The FRF-dataset names below are not in :mod:`lcmr_xr.conventions` yet; they are
written once here so the plotting modules never retype them.  When the lead adds
them to ``conventions.py`` these become plain re-exports.
"""

from __future__ import annotations

from lcmr_xr.conventions import INPUT, LIFT_PHASE, SECOND

# Variables and attributes of the FRF dataset (shared/conventions.md, "FRF dataset").
P_NAME = "P"
STD_SUFFIX = "_std"
S_NAME = "S"
PS_NAME = "PS"
NOISE_VARIANCE_U = "noise_variance_u"
NOISE_VARIANCE_Y = "noise_variance_y"
SLOW_NYQUIST = "slow_nyquist"
SAMPLING_PERIOD = "sampling_period"

# The column side of a lifted matrix carries the same dims with a suffix.
LIFT_PHASE2 = LIFT_PHASE + SECOND
INPUT2 = INPUT + SECOND


def long_name_and_units(attrs: dict, fallback_name: str) -> tuple[str, str | None]:
    """``(long_name, units)`` from ``attrs``; ``fallback_name`` replaces a missing long_name."""
    long_name = str(attrs.get("long_name") or fallback_name)
    units = attrs.get("units")
    return long_name, (None if units in (None, "") else str(units))


def quantity_label(attrs: dict, fallback_name: str, *, units: str | None = None) -> str:
    """``"long_name [units]"``; ``units`` overrides the attribute (e.g. ``rad/s``)."""
    long_name, attr_units = long_name_and_units(attrs, fallback_name)
    shown = units if units is not None else attr_units
    return f"{long_name} [{shown}]" if shown else long_name


def magnitude_label(attrs: dict, fallback_name: str, *, db: bool) -> str:
    """Label of a frequency-response magnitude: output units per input unit.

    A response's ``units`` are output units over input units (``"m/N"``); a plain unit
    (``"m"``) or a ``"/1"`` denominator means a dimensionless input, shown as ``m/unit``
    (metres per unit of input).  Decibels are relative to one of these; a dimensionless
    response (``"1"``) is plain dB.
    """
    long_name, units = long_name_and_units(attrs, fallback_name)
    ratio = None
    if units not in (None, "1"):
        numerator, slash, denominator = units.rpartition("/")
        if not slash:  # "m": per unit of a dimensionless input
            ratio = f"{units}/unit"
        elif denominator.strip() in ("1", ""):  # "m/1"
            ratio = f"{numerator}/unit"
        else:
            ratio = units
    if db:
        # 20 log10 |x| is only meaningful relative to a reference: one output unit per
        # input unit (implicit for a dimensionless response).
        return f"{long_name} [dB re 1 {ratio}]" if ratio else f"{long_name} [dB]"
    return f"{long_name} [{ratio or units}]" if (ratio or units) else long_name


def phase_label(attrs: dict, fallback_name: str) -> str:
    """Label of a phase axis, always in degrees."""
    long_name, _ = long_name_and_units(attrs, fallback_name)
    return f"{long_name} phase [deg]"


def lifted_channel_label(phase: int, channel: str) -> str:
    """``"phase 0 vcm"``: one row or column of a lifted matrix."""
    return f"phase {int(phase)} {channel}"


def entry_title(name: str, row: str, column: str) -> str:
    """``"S[phase 0 vcm <- phase 1 pzt]"``: the entry mapping ``column`` to ``row``."""
    return f"{name}[{row} <- {column}]"
