"""Tests of lcmr_xr.plot against synthetic FRF datasets with known values."""

from __future__ import annotations

import doctest
import importlib
import math
import os
import warnings

import matplotlib

matplotlib.use("Agg")  # before pyplot: no display on the test machines

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402
import xarray as xr  # noqa: E402
from hypothesis import given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402
from matplotlib.collections import PolyCollection  # noqa: E402
from matplotlib.lines import Line2D  # noqa: E402

import lcmr_xr.plot  # noqa: E402
from lcmr_xr.conventions import CONVENTIONS  # noqa: E402
from lcmr_xr.plot import (  # noqa: E402
    BodePlot,
    LiftedPlot,
    NoisePlot,
    bode,
    lifted,
    noise,
    save_figure,
)

TH = 1e-3
FACTOR = 4
N = 128
K95 = math.sqrt(math.log(20.0))  # 95 % radius of a circular complex Gaussian, in std
# The functions bode/lifted shadow their modules as attributes of lcmr_xr.plot.
BODE_MODULE = importlib.import_module("lcmr_xr.plot.bode")
LIFTED_MODULE = importlib.import_module("lcmr_xr.plot.lifted")
SHARED_MODULE = importlib.import_module("lcmr_xr.plot._shared")


@pytest.fixture(autouse=True)
def _close_figures():
    yield
    plt.close("all")


def plant(f, n_outputs=1):
    """Exact FRF (frequency, output, input): a resonance with a delay, and a first-order pzt."""
    s = 2j * np.pi * np.asarray(f, dtype=float)
    wn, zeta = 2 * np.pi * 60.0, 0.05
    # The 3-sample delay drives the vcm phase well past -180 deg, so unwrapping matters.
    vcm = 1e3 / (s**2 + 2 * zeta * wn * s + wn**2) * np.exp(-3 * s * TH)
    pzt = 2e2 / (s + 2 * np.pi * 100.0)
    one = np.stack([vcm, pzt], axis=-1)[:, None, :]
    return np.concatenate([(o + 1) * one for o in range(n_outputs)], axis=1)


def attrs(long_name, units="1"):
    return {"long_name": long_name, "units": units}


def make_frf(*, n_outputs=1, leading=None, zero_bin=None, nan_bin=None):
    """FRF dataset of the contract's shape: 2 inputs, n outputs, a made-up P_std."""
    k = np.arange(N // 2 + 1)
    f = k / (N * TH)
    outputs = ["position", "velocity", "force"][:n_outputs]
    inputs = ["vcm", "pzt"]
    P = plant(f, n_outputs)
    # Grows with frequency so the 95 % band reaches zero at the top bins.
    P_std = 0.1 * np.abs(P) * (1.0 + 20.0 * (f / f[-1]) ** 2)[:, None, None]
    if zero_bin is not None:
        P[zero_bin] = 0.0
    if nan_bin is not None:
        P[nan_bin] = np.nan
        P_std[nan_bin] = np.nan

    m_count = N // FACTOR
    fs = np.arange(m_count) / (m_count * FACTOR * TH)
    m = np.arange(m_count)[:, None, None, None, None]
    j, c, j2, c2 = np.ix_(range(FACTOR), range(2), range(FACTOR), range(2))
    # Distinct magnitude per entry, (m + 1) * code, so a misplaced panel is detected.
    S = (m + 1) * (1 + j + 10 * c + 100 * j2 + 1000 * c2) * np.exp(0.3j * (m + j - j2))
    o, j2_, c2_ = np.ix_(range(n_outputs), range(FACTOR), range(2))
    PS = (np.arange(m_count)[:, None, None, None] + 2.0) * (1 + o + 10 * j2_ + 100 * c2_) * (1 - 1j)
    ju, cu = np.ix_(range(FACTOR), range(2))
    noise_u = 1e-4 * (1 + np.arange(m_count)[:, None, None]) * (1 + ju + 10 * cu)
    noise_y = 1e-6 * (1 + np.arange(m_count)[:, None]) * (1 + np.arange(n_outputs))

    fdims = ("frequency", "output", "input")
    sdims = ("slow_frequency", "lift_phase", "input", "lift_phase2", "input2")
    psdims = ("slow_frequency", "output", "lift_phase2", "input2")
    ds = xr.Dataset(
        {
            "P": (fdims, P, {"long_name": "plant FRF", "units": "m/1"}),
            "P_std": (fdims, P_std, {"long_name": "std of plant FRF", "units": "m/1"}),
            "S": (sdims, S, {"long_name": "lifted sensitivity", "units": "1"}),
            "S_std": (sdims, 0.2 * np.abs(S), {"long_name": "std of S", "units": "1"}),
            "PS": (psdims, PS, {"long_name": "lifted process sensitivity", "units": "m"}),
            "PS_std": (psdims, 0.1 * np.abs(PS), {"long_name": "std of PS", "units": "m"}),
            "noise_variance_u": (
                ("slow_frequency", "lift_phase", "input"), noise_u,
                {"long_name": "residual variance of u", "units": "1"},
            ),
            "noise_variance_y": (
                ("slow_frequency", "output"), noise_y,
                {"long_name": "residual variance of y", "units": "m2"},
            ),
            "condition": ("slow_frequency", np.ones(m_count), attrs("condition number")),
            "ill_posed": ("slow_frequency", np.zeros(m_count, bool), attrs("ill posed")),
        },
        coords={
            "frequency": ("frequency", f, {"units": "Hz", "long_name": "frequency"}),
            "slow_frequency": ("slow_frequency", fs, attrs("slow frequency", "Hz")),
            "output": ("output", outputs, {"units": "1", "long_name": "output"}),
            "input": ("input", inputs, {"units": "1", "long_name": "input"}),
            "input2": ("input2", inputs, {"units": "1", "long_name": "input"}),
            "lift_phase": ("lift_phase", np.arange(FACTOR), attrs("lift phase")),
            "lift_phase2": ("lift_phase2", np.arange(FACTOR), attrs("lift phase")),
        },
        attrs={
            "factor": FACTOR, "sampling_period": TH, "slow_nyquist": 1 / (2 * FACTOR * TH),
            "method": "lrm", "window": 30, "degrees": [3, 3, 3], "conventions": CONVENTIONS,
        },
    )
    if leading:
        ds = xr.concat([ds, ds], dim=leading)
    return ds


def db(x):
    return 20 * np.log10(np.abs(x))


def at_bins(line, f):
    """y data of ``line`` at the frequencies ``f`` (drops the NaN breaks a wrapped phase gets)."""
    x, y = line.get_xdata(), line.get_ydata()
    keep = np.isin(x, f)
    np.testing.assert_array_equal(x[keep], f)
    return y[keep]


# ------------------------------------------------------------------------------ bode


@pytest.mark.parametrize(
    "n_outputs, phase, shape", [(1, True, (2, 2)), (1, False, (1, 2)), (2, True, (4, 2))]
)
def test_bode_grid_shape_and_result_object(n_outputs, phase, shape):
    result = bode(make_frf(n_outputs=n_outputs), phase=phase)
    assert isinstance(result, BodePlot)
    assert result.axes.shape == shape
    assert all(a.figure is result.figure for a in result.axes.flat)
    assert len(result.lines) == n_outputs * 2
    for pair in result.lines.values():
        assert len(pair["estimate"]) == (2 if phase else 1)
        assert all(isinstance(line, Line2D) for line in pair["estimate"])


def test_bode_magnitude_is_db_of_estimate_without_dc():
    frf = make_frf(n_outputs=2)
    result = bode(frf)
    f = frf.frequency.values[1:]  # DC skipped on the log axis
    for o, out in enumerate(["position", "velocity"]):
        for i, inp in enumerate(["vcm", "pzt"]):
            mag_line = result.lines[(out, inp)]["estimate"][0]
            assert mag_line.axes is result.axes[2 * o, i]
            np.testing.assert_allclose(mag_line.get_xdata(), f, rtol=0, atol=0)
            np.testing.assert_allclose(mag_line.get_ydata(), db(frf.P.values[1:, o, i]), rtol=1e-12)
    assert result.axes[0, 0].get_xscale() == "log"


def test_bode_absolute_magnitude_and_rad_per_s():
    frf = make_frf()
    result = bode(frf, db=False, hz=False)
    line = result.lines[("position", "pzt")]["estimate"][0]
    np.testing.assert_allclose(line.get_xdata(), 2 * np.pi * frf.frequency.values[1:], rtol=1e-15)
    np.testing.assert_allclose(line.get_ydata(), np.abs(frf.P.values[1:, 0, 1]), rtol=1e-12)
    assert result.axes[0, 0].get_yscale() == "log"
    assert result.axes[0, 0].get_ylabel() == "plant FRF [m/unit]"  # units "m/1": per input unit
    assert result.axes[-1, 0].get_xlabel() == "frequency [rad/s]"


def test_bode_phase_unwrapped_and_wrapped():
    frf = make_frf()
    wrapped_expected = np.degrees(np.angle(frf.P.values[1:, 0, 0]))
    unwrapped = bode(frf, unwrap=True).lines[("position", "vcm")]["estimate"][1].get_ydata()
    wrapped_line = bode(frf, unwrap=False).lines[("position", "vcm")]["estimate"][1]
    wrapped = at_bins(wrapped_line, frf.frequency.values[1:])
    np.testing.assert_allclose(wrapped, wrapped_expected, rtol=1e-12)
    # Same angle modulo 360, continuous, and it really leaves (-180, 180].
    np.testing.assert_allclose(np.mod(unwrapped - wrapped + 180, 360) - 180, 0, atol=1e-9)
    assert np.max(np.abs(np.diff(unwrapped))) < 180
    assert unwrapped.min() < -270
    np.testing.assert_allclose(unwrapped, np.degrees(np.unwrap(np.angle(frf.P.values[1:, 0, 0]))))


def test_bode_labels_and_titles_from_attrs():
    result = bode(make_frf(n_outputs=2))
    assert result.axes[0, 0].get_ylabel() == "plant FRF [dB re 1 m/unit]"
    assert result.axes[1, 0].get_ylabel() == "plant FRF phase [deg]"
    assert result.axes[2, 0].get_ylabel() == "plant FRF [dB re 1 m/unit]"
    assert result.axes[0, 1].get_ylabel() == ""  # only the first column is labelled
    assert result.axes[-1, 1].get_xlabel() == "frequency [Hz]"
    assert result.axes[0, 1].get_title() == "position <- pzt"
    assert result.axes[2, 0].get_title() == "velocity <- vcm"


@pytest.mark.parametrize(
    "band, k", [(0.95, K95), (0.5, math.sqrt(math.log(2.0))), (0.99, math.sqrt(math.log(100.0)))]
)
def test_bode_band_edges_are_magnitude_plus_minus_k_std(band, k):
    frf = make_frf()
    pair = bode(frf, band=band).lines[("position", "vcm")]
    upper, lower, fill = pair["band"]
    assert isinstance(fill, PolyCollection)
    mag = np.abs(frf.P.values[1:, 0, 0])
    radius = k * frf.P_std.values[1:, 0, 0]
    np.testing.assert_allclose(upper.get_ydata(), db(mag + radius), rtol=1e-12)
    positive = mag - radius > 0
    assert positive.any() and (~positive).any()  # the fixture exercises both cases
    # The band is clipped 20 dB under the lowest point of the estimate: the edge line
    # stops there (no spike towards zero), the fill goes down to the floor.
    floor = 0.1 * mag.min()
    above = mag - radius > floor
    assert (positive & ~above).any() or band != 0.95  # a positive edge under the floor exists
    np.testing.assert_allclose(lower.get_ydata()[above], db(mag - radius)[above], rtol=1e-12)
    assert np.isnan(lower.get_ydata()[~above]).all()
    fill_y = np.concatenate([p.vertices[:, 1] for p in fill.get_paths()])
    assert fill_y.min() == pytest.approx(db(floor), rel=1e-12)
    assert (fill_y >= db(floor) - 1e-9).all()


@settings(max_examples=40, deadline=None)
@given(
    band=st.floats(0.01, 0.999),
    mag=st.lists(st.floats(1e-6, 1e6), min_size=1, max_size=8),
    rel=st.floats(0.0, 3.0),
)
def test_band_edges_bracket_the_magnitude(band, mag, rel):
    """Upper edge = |P| + k std exactly; lower edge is below |P| and positive."""
    values = np.asarray(mag) * np.exp(1j * np.arange(len(mag)))
    sigma = rel * np.asarray(mag)
    k = SHARED_MODULE.confidence_radius(band)
    assert k == pytest.approx(math.sqrt(-math.log(1 - band)), rel=1e-12)
    upper, lower, _ = SHARED_MODULE._band_edges(values, sigma, k)
    np.testing.assert_allclose(upper, np.abs(values) + k * sigma, rtol=1e-12)
    assert np.all(lower > 0) and np.all(lower <= np.abs(values) * (1 + 1e-12))


def test_bode_no_band_without_std_or_when_disabled():
    frf = make_frf()
    assert bode(frf, band=None).lines[("position", "vcm")]["band"] == []
    assert bode(frf.P).lines[("position", "vcm")]["band"] == []  # bare DataArray: no std


@pytest.mark.parametrize("band", [0.0, 1.0, 1.5, -0.1, "95%", True])
def test_bode_rejects_bad_band(band):
    with pytest.raises(ValueError, match="between 0 and 1"):
        bode(make_frf(), band=band)
    with pytest.raises(ValueError, match="between 0 and 1"):
        bode(make_frf().P, band=band)  # no P_std to draw, but still a wrong argument
    with pytest.raises(ValueError, match="between 0 and 1"):
        lifted(make_frf(), band=band)


def test_bode_truth_on_same_grid_is_selected_exactly():
    frf = make_frf()
    truth = xr.DataArray(plant(frf.frequency.values), coords=frf.P.coords, dims=frf.P.dims)
    pair = bode(frf, truth=truth).lines[("position", "pzt")]
    mag, ph = pair["truth"]
    assert mag.get_linestyle() == "--"
    expected = plant(frf.frequency.values[1:])[:, 0, 1]
    np.testing.assert_allclose(mag.get_ydata(), db(expected), rtol=1e-12)
    # Truth equal to the estimate: phase drawn on the same branch as the estimate.
    np.testing.assert_allclose(ph.get_ydata(), pair["estimate"][1].get_ydata(), atol=1e-9)


def test_bode_truth_interpolated_from_finer_grid_and_reordered_labels():
    frf = make_frf()
    f_fine = np.linspace(0, frf.frequency.values[-1], 1001)
    exact = plant(f_fine)[:, :, ::-1]  # labels given in the other order
    truth = xr.DataArray(
        exact, dims=("frequency", "output", "input"),
        coords={"frequency": f_fine, "output": ["position"], "input": ["pzt", "vcm"]},
    )
    line = bode(frf, truth=truth).lines[("position", "vcm")]["truth"][0]
    f = frf.frequency.values[1:]
    col = exact[:, 0, 1]
    expected = np.interp(f, f_fine, col.real) + 1j * np.interp(f, f_fine, col.imag)
    np.testing.assert_allclose(line.get_ydata(), db(expected), rtol=1e-12)
    # And close to the exact value: the interpolation is of the right quantity.
    np.testing.assert_allclose(line.get_ydata(), db(plant(f)[:, 0, 0]), atol=0.2)


def test_bode_truth_frequency_only_broadcasts_and_outside_range_is_nan():
    frf = make_frf()
    f_short = frf.frequency.values[:20]
    truth = xr.DataArray(np.ones(20, complex), dims=("frequency",), coords={"frequency": f_short})
    for pair in bode(frf, truth=truth).lines.values():
        y = pair["truth"][0].get_ydata()
        np.testing.assert_allclose(y[:19], 0.0, atol=1e-12)  # |1| = 0 dB
        assert np.isnan(y[19:]).all()


def test_bode_truth_missing_label_rejected():
    frf = make_frf()
    truth = frf.P.sel(input=["vcm"])
    with pytest.raises(ValueError, match=r"lacks input label\(s\) \['pzt'\]"):
        bode(frf, truth=truth)
    with pytest.raises(TypeError, match="DataArray"):
        bode(frf, truth=np.ones(3))


def test_bode_truth_in_rad_per_s_is_refused():
    """The estimate's frequency had to be in Hz, the truth's was read as Hz whatever its
    units: an exact FRF on rad/s (python-control's omega) was drawn at 2 pi times its
    frequencies without a word.  Refused with the conversion, which then draws it right."""
    frf = make_frf()
    rad = frf.P.assign_coords(frequency=(frf.frequency * 2 * np.pi).assign_attrs(units="rad/s"))
    with pytest.raises(ValueError, match=r"truth: coordinate 'frequency' has units 'rad/s'.*Hz"):
        bode(frf, truth=rad)
    hz = frf.P.assign_coords(frequency=frf.frequency.assign_attrs(units="Hz"))
    drawn = bode(frf, truth=hz).lines
    for (out, inp), pair in drawn.items():
        np.testing.assert_allclose(pair["truth"][0].get_ydata(), pair["estimate"][0].get_ydata(),
                                   rtol=1e-9, atol=1e-9)


def test_bode_nyquist_line_position_and_sources():
    frf = make_frf()
    nyq = 1 / (2 * FACTOR * TH)
    lines = bode(frf).lines[("position", "vcm")]["nyquist"]
    assert len(lines) == 2
    for line in lines:
        np.testing.assert_allclose(line.get_xdata(), [nyq, nyq])
        assert line.get_linestyle() == "--"
    # rad/s axis
    line = bode(frf, hz=False).lines[("position", "pzt")]["nyquist"][0]
    np.testing.assert_allclose(line.get_xdata(), [2 * np.pi * nyq] * 2)
    # From factor and sampling_period when slow_nyquist is absent.
    without = frf.copy()
    del without.attrs["slow_nyquist"]
    line = bode(without).lines[("position", "vcm")]["nyquist"][0]
    np.testing.assert_allclose(line.get_xdata(), [nyq, nyq])
    # Explicit value, and switched off; a bare DataArray without attrs draws none.
    line = bode(frf, nyquist=42.0).lines[("position", "vcm")]["nyquist"][0]
    np.testing.assert_allclose(line.get_xdata(), [42.0, 42.0])
    assert bode(frf, nyquist=False).lines[("position", "vcm")]["nyquist"] == []
    assert bode(frf.P).lines[("position", "vcm")]["nyquist"] == []
    with pytest.raises(ValueError, match="positive frequency in Hz"):
        bode(frf, nyquist=-1.0)


def test_bode_reuses_axes_for_overlay_and_legend():
    frf = make_frf()
    first = bode(frf, label="LRM")
    second = bode(frf * 2, ax=first.axes, label="doubled")
    assert second.figure is first.figure
    assert all(a is b for a, b in zip(second.axes.flat, first.axes.flat))
    assert len(first.axes[0, 0].get_lines()) >= 2 * 3  # estimate + 2 band edges each
    c1 = first.lines[("position", "vcm")]["estimate"][0].get_color()
    c2 = second.lines[("position", "vcm")]["estimate"][0].get_color()
    assert c1 != c2  # the overlay takes the next color of the cycle
    assert second.lines[("position", "vcm")]["band"][0].get_color() == c2
    labels = [t.get_text() for t in first.axes[0, 0].get_legend().get_texts()]
    assert sorted(labels) == sorted(["LRM", "doubled", "95% confidence", "slow Nyquist"])
    # an overlay with another long_name does not relabel the axes: the legend tells them apart
    ylabel = first.axes[0, 0].get_ylabel()
    other = frf.copy()
    other["P"].attrs["long_name"] = "something else"
    bode(other, ax=first.axes, label="other")
    assert first.axes[0, 0].get_ylabel() == ylabel and "something else" not in ylabel
    # plt.subplots squeezes a single column: shape (2,) is accepted for a (2, 1) grid.
    _, squeezed = plt.subplots(2, 1)
    assert bode(frf.sel(input=["vcm"]), ax=squeezed).axes.shape == (2, 1)


def test_bode_rejects_bad_ax():
    frf = make_frf()
    _, axes = plt.subplots(3, 2)
    with pytest.raises(ValueError, match=r"needs a grid of shape \(2, 2\)"):
        bode(frf, ax=axes)
    with pytest.raises(TypeError, match="matplotlib Axes"):
        bode(frf, ax=np.array([[1, 2], [3, 4]], dtype=object))


def test_bode_rejects_unknown_keyword():
    with pytest.raises(TypeError, match="linestyle"):
        bode(make_frf(), linestyle=":")


def test_bode_refuses_leading_dims_with_selection_hint():
    frf = make_frf(leading="experiment")
    with pytest.raises(ValueError, match=r"experiment=2.*isel\(experiment=0\)"):
        bode(frf)
    assert bode(frf.isel(experiment=1)).axes.shape == (2, 2)


def test_bode_rejects_wrong_inputs():
    frf = make_frf()
    with pytest.raises(TypeError, match="Dataset"):
        bode(frf.P.values)
    with pytest.raises(ValueError, match="no variable 'P'"):
        bode(frf.drop_vars("P"))
    with pytest.raises(ValueError, match=r"expand_dims"):
        bode(frf.P.isel(input=0, drop=True))
    in_rad = frf.P.assign_coords(frequency=("frequency", 2 * np.pi * frf.frequency.values,
                                            {"units": "rad/s"}))
    with pytest.raises(ValueError, match="units 'rad/s', but plots need Hz"):
        bode(in_rad)


def test_bode_refuses_a_real_frf_and_a_bad_color():
    """A real P (|P|, its phase lost) was drawn with phase 0/180 deg; a bad color reached
    matplotlib ("'blurple' is not a valid value for color") after the figure was made."""
    frf = make_frf()
    figures = plt.get_fignums()
    for real in (abs(frf.P), frf.P.real.astype(np.float32), abs(frf.P).round().astype(int)):
        with pytest.raises(ValueError, match=r"P is real \(.*\), but a frequency response is complex.*"
                                             r"P.astype\(complex\)"):
            bode(real)
    with pytest.raises(ValueError, match="P is real"):
        bode(frf.assign(P=abs(frf.P)))
    with pytest.raises(ValueError, match="truth is real"):
        bode(frf, truth=abs(frf.P))
    with pytest.raises(ValueError, match=r"P_std is real .*a standard deviation such as P_std\?\). Pass the "
                                         r"complex FRF \(P as lcmr_xr.identify returns it\)"):
        bode(frf.P_std)
    with pytest.raises(TypeError, match="must hold complex numbers.*bool"):
        bode(frf.P > 0)
    for color in ("blurple", (1.0, 0.2), (2.0, 0.0, 0.0), "#12345"):
        with pytest.raises(ValueError, match=r"color .* is not a matplotlib color; pass a color name"):
            bode(frf, color=color)
        with pytest.raises(ValueError, match="is not a matplotlib color"):
            lifted(frf, color=color)
    for color in (5, True, {"r": 1}):
        with pytest.raises(TypeError, match=r"color must be a matplotlib color, got"):
            bode(frf, color=color)
    assert plt.get_fignums() == figures  # refused before a figure was made
    for color in ("tab:red", "C1", "#1f77b4", "0.5", (0.1, 0.2, 0.5), (0.1, 0.2, 0.5, 0.8)):
        result = bode(frf, color=color)
        assert result.lines[("position", "vcm")]["estimate"][0].get_color() == color
        plt.close(result.figure)
    with pytest.raises(ValueError, match="S is real"):
        lifted(frf.assign(S=abs(frf.S)))


def test_bode_zero_and_nan_bins_are_gaps_without_warnings():
    frf = make_frf(zero_bin=5, nan_bin=9)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        result = bode(frf, db=True, unwrap=True)
        bode(frf)  # wrapped: the gaps are gaps there too
        bode(frf, db=False)
        result.figure.canvas.draw()
    pair = result.lines[("position", "vcm")]
    mag, ph = (line.get_ydata() for line in pair["estimate"])
    upper, lower = (line.get_ydata() for line in pair["band"][:2])
    # the lower edge also stops where it is clipped at the floor (20 dB under the minimum)
    p_vcm, radius = frf.P.values[1:, 0, 0], K95 * frf.P_std.values[1:, 0, 0]
    drawn = np.abs(p_vcm) > 0  # False at the zero and NaN bins (the gaps)
    clipped = drawn & (np.abs(p_vcm) - radius <= 0.1 * np.abs(p_vcm[drawn]).min())
    for arr in (mag, ph, upper, np.where(clipped, 0.0, lower)):
        assert np.isnan(arr[[4, 8]]).all()  # bins 5 and 9 minus DC
        assert np.isfinite(np.delete(arr, [4, 8])).all()
    # The unwrapped phase keeps going across the gaps.
    expected = np.degrees(np.unwrap(np.angle(np.delete(frf.P.values[1:, 0, 0], [4, 8]))))
    np.testing.assert_allclose(np.delete(ph, [4, 8]), expected, rtol=1e-12)


def test_bode_xlim_zooms_and_selects_bins():
    frf = make_frf()
    result = bode(frf, xlim=(20.0, 100.0), hz=False)
    f = frf.frequency.values
    inside = (f >= 20) & (f <= 100)
    line = result.lines[("position", "vcm")]["estimate"][0]
    np.testing.assert_allclose(line.get_xdata(), 2 * np.pi * f[inside])
    np.testing.assert_allclose(line.get_ydata(), db(frf.P.values[inside, 0, 0]), rtol=1e-12)
    np.testing.assert_allclose(result.axes[1, 1].get_xlim(), (2 * np.pi * 20, 2 * np.pi * 100))
    for bad in [(100.0, 20.0), (0.0, 10.0), (1.0,), "wide", (1.0, np.inf)]:
        with pytest.raises(ValueError, match="xlim"):
            bode(frf, xlim=bad)
    with pytest.raises(ValueError, match="No frequency bin"):
        bode(frf, xlim=(1000.0, 2000.0))


# ------------------------------------------------------------------------------ lifted


def test_lifted_S_grid_titles_and_magnitudes():
    frf = make_frf()
    result = lifted(frf)
    assert isinstance(result, LiftedPlot)
    assert result.axes.shape == (2 * FACTOR, 2 * FACTOR)
    fs = frf.slow_frequency.values[1:]
    for j, c, j2, c2 in [(0, 0, 1, 1), (3, 1, 0, 0), (2, 0, 2, 1)]:
        row, col = j * 2 + c, j2 * 2 + c2  # phase-major rows and columns
        names = ["vcm", "pzt"]
        key = (f"phase {j} {names[c]}", f"phase {j2} {names[c2]}")
        entry = result.lines[key]
        assert entry["estimate"][0].axes is result.axes[row, col]
        assert result.axes[row, col].get_title() == f"S[{key[0]} <- {key[1]}]"
        np.testing.assert_allclose(entry["estimate"][0].get_xdata(), fs)
        np.testing.assert_allclose(
            entry["estimate"][0].get_ydata(), db(frf.S.values[1:, j, c, j2, c2]), rtol=1e-12
        )
        upper = entry["band"][0].get_ydata()
        # S_std = 0.2 |S| in the fixture: upper edge |S| (1 + 0.2 k95).
        expected_upper = db(np.abs(frf.S.values[1:, j, c, j2, c2]) * (1 + 0.2 * K95))
        np.testing.assert_allclose(upper, expected_upper, rtol=1e-12)
    assert result.axes[0, 1].get_title() == "S[phase 0 vcm <- phase 0 pzt]"
    assert result.axes[0, 0].get_ylabel() == "lifted sensitivity [dB]"  # units "1"
    assert result.axes[-1, 0].get_xlabel() == "slow frequency [Hz]"


def test_lifted_PS_grid_and_values():
    frf = make_frf(n_outputs=2)
    result = lifted(frf, which="PS", db=False, band=None)
    assert result.axes.shape == (2, 2 * FACTOR)
    entry = result.lines[("velocity", "phase 3 pzt")]
    assert entry["band"] == []
    assert result.axes[1, 7].get_title() == "PS[velocity <- phase 3 pzt]"
    np.testing.assert_allclose(
        entry["estimate"][0].get_ydata(), np.abs(frf.PS.values[1:, 1, 3, 1]), rtol=1e-12
    )
    assert result.axes[0, 0].get_yscale() == "log"


def test_lifted_rejects_bad_arguments():
    frf = make_frf()
    with pytest.raises(ValueError, match="which must be one of"):
        lifted(frf, which="T")
    with pytest.raises(ValueError, match="no variable 'PS'"):
        lifted(frf.drop_vars("PS"), which="PS")
    with pytest.raises(TypeError, match="Dataset"):
        lifted(frf.S)
    # a direct-loop estimate (no S) was told to "choose which='S' or 'PS'", S included
    direct = frf.drop_vars(["S", "S_std"]).assign_attrs(closed_loop="direct")
    with pytest.raises(ValueError) as info:
        lifted(direct)
    assert "closed_loop='direct' estimate has no lifted sensitivity: plot which='PS'" in str(info.value)
    assert "which='S'" not in str(info.value)
    with pytest.raises(ValueError, match=r"isel\(experiment=0\)"):
        lifted(make_frf(leading="experiment"))
    _, axes = plt.subplots(2, 2)
    with pytest.raises(ValueError, match=r"shape \(8, 8\)"):
        lifted(frf, ax=axes)
    with pytest.raises(TypeError, match="unexpected keyword"):
        lifted(frf, bogus=1)


def test_lifted_reuses_axes():
    frf = make_frf()
    first = lifted(frf, which="PS")
    second = lifted(frf, which="PS", ax=first.axes, band=None)
    assert second.figure is first.figure
    assert len(first.axes[0, 0].get_lines()) == 3 + 1  # band edges + estimate, then estimate


# ------------------------------------------------------------------------------ noise


def test_noise_lines_equal_variances_on_log_axes():
    frf = make_frf(n_outputs=2)
    result = noise(frf)
    assert isinstance(result, NoisePlot)
    assert result.axes.shape == (2, 1)
    assert len(result.lines) == 2 + 2 * FACTOR
    fs = frf.slow_frequency.values[1:]
    y_line = result.lines[("noise_variance_y", "velocity")][0]
    assert y_line.axes is result.axes[0, 0]
    np.testing.assert_allclose(y_line.get_xdata(), fs)
    np.testing.assert_allclose(y_line.get_ydata(), frf.noise_variance_y.values[1:, 1], rtol=1e-15)
    u_line = result.lines[("noise_variance_u", "phase 2 pzt")][0]
    assert u_line.axes is result.axes[1, 0]
    expected = frf.noise_variance_u.values[1:, 2, 1]
    np.testing.assert_allclose(u_line.get_ydata(), expected, rtol=1e-15)
    for a in result.axes.flat:
        assert a.get_yscale() == "log" and a.get_xscale() == "log"
    # the plotting rule: labels are the variables' long_name [units] (they said "variance")
    assert result.axes[0, 0].get_ylabel() == "residual variance of y [m2]"
    assert result.axes[1, 0].get_ylabel() == "residual variance of u [1]"
    assert "phase 2 pzt" in [t.get_text() for t in result.axes[1, 0].get_legend().get_texts()]


def test_noise_zero_variance_is_gap_and_errors():
    frf = make_frf()
    frf["noise_variance_y"][3] = 0.0
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        result = noise(frf)
        result.figure.canvas.draw()
    assert np.isnan(result.lines[("noise_variance_y", "position")][0].get_ydata()[2])
    with pytest.raises(ValueError, match="no variable 'noise_variance_u'"):
        noise(frf.drop_vars("noise_variance_u"))
    with pytest.raises(ValueError, match=r"shape \(2, 1\)"):
        noise(frf, ax=plt.subplots(1, 3)[1])


# ------------------------------------------------------------------------------ saving


def test_save_figure_writes_png_atomically(tmp_path):
    result = bode(make_frf())
    path = save_figure(result, tmp_path / "bode.png", dpi=50)
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 1000
    assert os.listdir(tmp_path) == ["bode.png"]
    # Overwrite in place with a plain Figure.
    save_figure(result.figure, str(tmp_path / "bode.png"))
    assert os.listdir(tmp_path) == ["bode.png"]


def test_save_figure_failure_leaves_nothing(tmp_path, monkeypatch):
    result = bode(make_frf())

    def broken(*args, **kwargs):
        raise RuntimeError("disk full")

    monkeypatch.setattr(result.figure, "savefig", broken)
    with pytest.raises(RuntimeError, match="disk full"):
        save_figure(result, tmp_path / "bode.png")
    assert os.listdir(tmp_path) == []


def test_save_figure_rejects_bad_arguments(tmp_path):
    result = bode(make_frf())
    with pytest.raises(ValueError, match=r"ending in '.png'"):
        save_figure(result, tmp_path / "bode.pdf")
    with pytest.raises(FileNotFoundError, match="create it first"):
        save_figure(result, tmp_path / "missing" / "bode.png")
    with pytest.raises(TypeError, match="Figure"):
        save_figure(object(), tmp_path / "x.png")
    with pytest.raises(ValueError, match="dpi"):
        save_figure(result, tmp_path / "x.png", dpi=0)
    assert os.listdir(tmp_path) == []


# ------------------------------------------------------------------------------ docs


@pytest.mark.parametrize("module", [lcmr_xr.plot, BODE_MODULE, LIFTED_MODULE])
def test_docstring_examples_run(module):
    outcome = doctest.testmod(module, optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    assert outcome.attempted > 0
    assert outcome.failed == 0


@given(turns=st.integers(-5, 5), outlier=st.integers(-3, 3))
@settings(max_examples=30, deadline=None)
def test_truth_phase_moves_by_whole_turns_onto_the_estimate(turns, outlier):
    """The median offset decides: one bad first bin cannot pull the truth off by a turn."""
    reference = np.linspace(-30.0, -900.0, 40) + 5.0 * np.sin(np.arange(40))
    phase = np.linspace(-30.0, -900.0, 40) + 360.0 * turns
    reference[0] += 360.0 * outlier  # a noisy lowest bin that unwrapped onto another turn
    aligned = BODE_MODULE._align_phase(phase, reference)
    np.testing.assert_allclose(aligned, np.linspace(-30.0, -900.0, 40), atol=1e-9)


# ------------------------------------------------------------------------------ at a glance


def test_bode_phase_is_wrapped_by_default_and_broken_at_wraps():
    frf = make_frf()
    result = bode(frf, truth=frf.P)
    f = frf.frequency.values[1:]
    for inp in ("vcm", "pzt"):
        line = result.lines[("position", inp)]["estimate"][1]
        y = at_bins(line, f)
        expected = np.degrees(np.angle(frf.P.sel(input=inp).values[1:, 0]))
        np.testing.assert_allclose(y, np.where(expected <= -180, expected + 360, expected), rtol=1e-12)
        assert (y > -180).all() and (y <= 180).all()
        # drawn without vertical jumps: every wrap gets a NaN break between its two bins
        drawn = line.get_ydata()
        pieces = np.split(drawn, np.flatnonzero(np.isnan(drawn)))
        assert all(np.all(np.abs(np.diff(p[np.isfinite(p)])) < 180) for p in pieces)
        x = line.get_xdata()
        assert np.all(np.diff(x[~np.isnan(x)]) > 0)
        # the truth is drawn on the same (wrapped) branch
        np.testing.assert_array_equal(result.lines[("position", inp)]["truth"][1].get_ydata(), drawn)
    vcm_breaks = np.isnan(result.lines[("position", "vcm")]["estimate"][1].get_ydata()).sum()
    assert vcm_breaks >= 1  # the 3-sample delay wraps the vcm phase
    phase_ax = result.axes[1, 0]
    assert list(phase_ax.get_yticks()) == [-180, -90, 0, 90, 180]
    assert phase_ax.get_ylim() == (-225.0, 225.0)
    # -180 exactly is shown as +180 (the interval is half-open)
    assert BODE_MODULE._phase_deg(np.array([complex(-1.0, -0.0)]), False)[0] == 180.0


@pytest.mark.parametrize("units, db, label", [
    ("m", True, "plant FRF [dB re 1 m/unit]"),
    ("m/1", False, "plant FRF [m/unit]"),
    ("m/N", True, "plant FRF [dB re 1 m/N]"),
    ("m/(V s)", False, "plant FRF [m/(V s)]"),
    ("1", True, "plant FRF [dB]"),
])
def test_magnitude_is_labelled_output_units_per_input_unit(units, db, label):
    frf = make_frf()
    frf["P"].attrs["units"] = units
    assert bode(frf, db=db).axes[0, 0].get_ylabel() == label


def test_lower_band_edge_is_clipped_not_a_spike():
    frf = make_frf()
    # a lower edge that comes very close to zero without reaching it: a spike in dB before
    p = frf.P.values[1:, 0, 0]
    frf["P_std"][20, 0, 0] = (np.abs(frf.P.values[20, 0, 0]) * (1 - 1e-9)) / K95
    result = bode(frf, truth=frf.P)
    mag_ax = result.axes[0, 0]
    floor_db = db(0.1 * np.abs(p).min())
    lower = result.lines[("position", "vcm")]["band"][1].get_ydata()
    assert np.isnan(lower[19])  # clipped: the edge line stops at the floor
    assert np.nanmin(lower) > floor_db
    bottom, top = mag_ax.get_ylim()
    # the axis ends just under the floor (matplotlib's 5 % margin), not 180 dB lower
    assert floor_db - 0.06 * (top - floor_db) <= bottom <= floor_db


def test_legend_lists_only_what_is_in_view():
    frf = make_frf()
    nyquist = frf.attrs["slow_nyquist"]  # 125 Hz
    wide = bode(frf, truth=frf.P, label="LRM")
    texts = [t.get_text() for t in wide.axes[0, 0].get_legend().get_texts()]
    assert sorted(texts) == ["95% confidence", "LRM", "slow Nyquist", "truth"]
    zoom = bode(frf, truth=frf.P.sel(frequency=slice(0, 150)), label="LRM", xlim=(200.0, 480.0))
    assert nyquist < 200.0
    texts = [t.get_text() for t in zoom.axes[0, 0].get_legend().get_texts()]
    assert sorted(texts) == ["95% confidence", "LRM"]  # Nyquist line and truth are outside


def test_zoomed_log_axis_gets_enough_ticks():
    frf = make_frf()
    result = bode(frf, xlim=(200.0, 480.0))
    for a in result.axes.flat:
        lo, hi = a.get_xlim()
        ticks = [t for t in a.get_xticks() if lo <= t <= hi]
        assert ticks == [200.0, 300.0, 400.0], ticks  # a log axis labels none of them
        formatter = a.xaxis.get_major_formatter()
        assert formatter(300.0) == "300" and formatter(40000.0) == "40k"
    # a wide view keeps matplotlib's decade ticks
    wide = bode(frf)
    assert type(wide.axes[0, 0].xaxis.get_major_formatter()).__name__.startswith("Log")
    # the lifted plots too
    lifted_zoom = lifted(frf, which="PS", xlim=(20.0, 100.0))
    lo, hi = lifted_zoom.axes[0, 0].get_xlim()
    ticks = [t for t in lifted_zoom.axes[0, 0].get_xticks() if lo <= t <= hi]
    assert ticks == [20.0, 40.0, 60.0, 80.0, 100.0], ticks


def test_bode_title_and_cli_plot_title(tmp_path, monkeypatch):
    assert bode(make_frf(), title="LRM, window 30").figure.get_suptitle() == "LRM, window 30"
    assert bode(make_frf()).figure.get_suptitle() == ""
    from lcmr_xr import cli

    exp_path = tmp_path / "exp.nc"
    assert cli.main(["simulate", "-o", str(exp_path), "--samples", "800", "--noiseless"]) == 0
    saved = {}
    monkeypatch.setattr(lcmr_xr.plot, "save_figure",
                        lambda result, path: saved.update(title=result.figure.get_suptitle()))
    assert cli.main(["identify", str(exp_path), "-o", str(tmp_path / "frf.nc"), "--window", "20",
                     "--plot", str(tmp_path / "bode.png")]) == 0
    assert saved["title"] == ("exp.nc: lifted indirect closed-loop LRM FRF estimate "
                              "(window 20, degrees 3, 3, 3)")


def test_wrapped_estimate_is_drawn_beside_a_truth_at_the_wrap():
    frf = make_frf().isel(input=[0])
    f = frf.frequency.values
    truth_phase = np.where(f < 200, 179.0, 100.0)
    est_phase = np.where(f < 200, -179.0, -100.0)  # agrees, then disagrees by 160 deg
    frf["P"][:, 0, 0] = np.exp(1j * np.radians(est_phase))
    truth = frf.P.copy(data=np.exp(1j * np.radians(truth_phase))[:, None, None])
    pair = bode(frf, truth=truth).lines[("position", "vcm")]
    drawn = at_bins(pair["estimate"][1], f[1:])
    low = f[1:] < 200
    np.testing.assert_allclose(drawn[low], 181.0, rtol=1e-12)  # beside the truth at 179
    np.testing.assert_allclose(drawn[~low], -100.0, rtol=1e-12)  # 260 would leave the axis
    np.testing.assert_allclose(at_bins(pair["truth"][1], f[1:]), truth_phase[1:], rtol=1e-12)
    # without a truth the estimate is strictly wrapped
    alone = at_bins(bode(frf).lines[("position", "vcm")]["estimate"][1], f[1:])
    np.testing.assert_allclose(alone, est_phase[1:], rtol=1e-12)
