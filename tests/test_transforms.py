"""Labelled lift/unlift and DFTs: exact round trips, numpy.fft agreement, laziness, errors."""

from __future__ import annotations

import re

import dask
import dask.array as da
import numpy as np
import pytest
import xarray as xr
from hypothesis import given, settings
from hypothesis import strategies as st

from lcmr_xr.conventions import DFT_SCALING, LIFT_PHASE
from lcmr_xr.transforms import dft, fast_spectrum_from_lifted, idft, lift, unlift


def _signal(n, th=1e-3, extra=(), seed=0, complex_=False, name="u"):
    rng = np.random.default_rng(seed)
    shape = tuple(s for _, s in extra) + (n,)
    data = rng.standard_normal(shape)
    if complex_:
        data = data + 1j * rng.standard_normal(shape)
    coords = {"time": ("time", np.arange(n) * th, {"units": "s", "long_name": "time",
                                                    "standard_name": "time", "axis": "T"})}
    for d, s in extra:
        coords[d] = (d, [f"{d}{i}" for i in range(s)], {"units": "1", "long_name": d})
    return xr.DataArray(data, dims=tuple(d for d, _ in extra) + ("time",), coords=coords,
                        name=name, attrs={"units": "V", "long_name": "plant input"})


def _exploding(shape, chunks):
    """A dask array whose computation fails: proves that nothing was computed."""

    def boom(block):
        raise AssertionError("the data were computed")

    return da.zeros(shape, chunks=chunks).map_blocks(boom, meta=np.array((), float))


# --- lift / unlift --------------------------------------------------------------------


@st.composite
def lift_cases(draw):
    factor = draw(st.integers(1, 5))
    m = draw(st.integers(1, 6))
    n_extra = draw(st.integers(0, 2))
    extra = [(f"d{i}", draw(st.integers(1, 3))) for i in range(n_extra)]
    order = draw(st.permutations(["time"] + [d for d, _ in extra]))
    seed = draw(st.integers(0, 1000))
    return factor, m, extra, list(order), seed


@settings(deadline=None, max_examples=40)
@given(lift_cases())
def test_lift_round_trip_identical_any_dims(case):
    factor, m, extra, order, seed = case
    x = _signal(m * factor, extra=extra, seed=seed).transpose(*order)
    x = x.assign_coords(sample=("time", np.arange(m * factor) * 2, {"units": "1", "long_name": "n"}))
    lifted = lift(x, factor)
    assert lifted.sizes["slow_time"] == m and lifted.sizes[LIFT_PHASE] == factor
    for l in range(m):
        for j in range(factor):
            xr.testing.assert_equal(
                lifted.isel(slow_time=l, lift_phase=j, drop=True).reset_coords(drop=True),
                x.isel(time=l * factor + j, drop=True).reset_coords(drop=True),
            )
    xr.testing.assert_identical(unlift(lifted), x)
    # unlift does not care where the two dims sit
    shuffled = lifted.transpose(*reversed(lifted.dims))
    xr.testing.assert_identical(unlift(shuffled).transpose(*x.dims), x)


def test_lift_coordinates_and_attrs():
    x = _signal(12, th=0.25)
    lifted = lift(x, 3)
    np.testing.assert_array_equal(lifted.slow_time.values, x.time.values[::3])
    assert lifted.slow_time.attrs == x.time.attrs
    assert lifted.lift_phase.values.tolist() == [0, 1, 2]
    assert lifted.lift_phase.attrs["units"] == "1" and "long_name" in lifted.lift_phase.attrs
    assert lifted.attrs == x.attrs and lifted.name == "u"


def test_lift_factor_from_attrs_and_missing_factor():
    x = _signal(8)
    with pytest.raises(ValueError, match=r"factor=F.*attrs\['factor'\]"):
        lift(x)
    x.attrs["factor"] = 4
    assert lift(x).sizes[LIFT_PHASE] == 4


def test_lift_refuses_non_multiple():
    with pytest.raises(ValueError, match=r"N=10.*F=3.*Trim the signal to 9"):
        lift(_signal(10), 3)


def test_lift_dataset_passes_slow_variables_through():
    factor = 2
    u = _signal(8, th=0.5)
    y = xr.DataArray(np.arange(4.0), dims="slow_time",
                     coords={"slow_time": ("slow_time", np.arange(4) * 1.0, {"units": "s"})},
                     attrs={"units": "m"})
    ds = xr.Dataset({"u": u, "y": y}, attrs={"factor": factor})
    lifted = lift(ds)
    xr.testing.assert_identical(lifted["y"], ds["y"])
    assert lifted["u"].dims == ("slow_time", LIFT_PHASE)
    xr.testing.assert_identical(unlift(lifted), ds)
    bad = ds.assign_coords(slow_time=ds.slow_time + 0.25)
    with pytest.raises(ValueError, match="does not match time"):
        lift(bad)


def test_lift_round_trip_of_an_experiment_dataset():
    from lcmr_xr.experiment import experiment

    rng = np.random.default_rng(3)
    ds = experiment(rng.standard_normal((2, 12, 2)), rng.standard_normal((2, 12, 2)),
                    rng.standard_normal((2, 4, 1)), factor=3, sampling_period=1 / 100800)
    lifted = lift(ds)  # factor from the attribute; y stays on slow_time
    assert lifted["u"].dims == ("experiment", "slow_time", LIFT_PHASE, "input")
    xr.testing.assert_identical(lifted["y"], ds["y"])
    xr.testing.assert_identical(unlift(lifted), ds)


def test_lift_and_unlift_stay_lazy():
    n = 12
    x = xr.DataArray(_exploding((2, n), (1, 5)), dims=("e", "time"),
                     coords={"time": np.arange(n) * 0.1})
    lifted = lift(x, 3)
    assert dask.is_dask_collection(lifted.data)
    back = unlift(lifted)
    assert dask.is_dask_collection(back.data)
    # and the values are right once computed (on a computable array)
    real = xr.DataArray(da.arange(24.0, chunks=5).reshape(2, 12), dims=("e", "time"),
                        coords={"time": np.arange(n) * 0.1})
    np.testing.assert_array_equal(lift(real, 3).values, np.arange(24.0).reshape(2, 4, 3))
    xr.testing.assert_identical(unlift(lift(real, 3)).compute(), real.compute())


# --- dft ------------------------------------------------------------------------------


@pytest.mark.parametrize("n", [1 + 0, 7, 16])
def test_dft_matches_numpy_fft(n):
    if n < 2:
        with pytest.raises(ValueError, match="at least 2"):
            dft(_signal(1))
        return
    th = 2e-3
    x = _signal(n, th=th, extra=[("input", 2)])
    spec = dft(x)
    assert spec.dims == ("input", "frequency")
    np.testing.assert_allclose(spec.values, np.fft.fft(x.values, axis=-1), rtol=1e-13, atol=1e-13)
    np.testing.assert_allclose(spec.frequency.values, np.arange(n) / (n * th), rtol=1e-14)
    assert spec.frequency.attrs["units"] == "Hz"
    assert spec.attrs["units"] == "V" and spec.attrs["long_name"] == "DFT of plant input"
    assert spec.attrs[DFT_SCALING] == "sum"
    one = dft(x, one_sided=True)
    np.testing.assert_allclose(one.values, np.fft.rfft(x.values, axis=-1), rtol=1e-13, atol=1e-13)
    np.testing.assert_allclose(one.frequency.values, np.arange(n // 2 + 1) / (n * th), rtol=1e-14)


@settings(deadline=None, max_examples=30)
@given(n=st.integers(2, 64), seed=st.integers(0, 10**6), complex_=st.booleans())
def test_parseval(n, seed, complex_):
    x = _signal(n, seed=seed, complex_=complex_)
    spec = dft(x)
    energy = float((abs(x) ** 2).sum())
    assert float((abs(spec) ** 2).sum()) / n == pytest.approx(energy, rel=1e-12)


def _assert_round_trip(x, back):
    xr.testing.assert_allclose(back, x, rtol=1e-12, atol=1e-12 * float(abs(x).max()))
    assert back.dtype == x.dtype
    xr.testing.assert_identical(back.copy(data=x.values), x)


@pytest.mark.parametrize(
    "time",
    [
        np.arange(10) * 0.1,
        np.arange(10) / 3.0,
        np.linspace(0.3, 2.1, 10),
        2.5 + np.arange(10) * 1e-4,
        np.arange(10) * 0.1 + np.array([0, 1, -1, 0, 2, 0, 0, -2, 0, 1]) * 1e-12,
    ],
)
@pytest.mark.parametrize("one_sided", [False, True])
def test_idft_restores_signal_and_time_coordinate_exactly(time, one_sided):
    x = _signal(10, extra=[("input", 2)]).assign_coords(
        time=("time", time, {"units": "s", "long_name": "time"})
    )
    _assert_round_trip(x, idft(dft(x, one_sided=one_sided)))


def test_idft_complex_and_odd_and_no_long_name():
    x = _signal(9, complex_=True)
    _assert_round_trip(x, idft(dft(x)))
    y = _signal(9)
    del y.attrs["long_name"]
    back = idft(dft(y, one_sided=True))
    assert "long_name" not in back.attrs
    _assert_round_trip(y, back)
    with pytest.raises(ValueError, match="real signal"):
        dft(x, one_sided=True)


def test_dft_dataset_transforms_only_variables_with_dim():
    u = _signal(8, th=0.5)
    y = xr.DataArray(np.arange(4.0), dims="slow_time", coords={"slow_time": np.arange(4) * 1.0})
    ds = xr.Dataset({"u": u, "y": y}, attrs={"factor": 2})
    spec = dft(ds, "time")
    xr.testing.assert_identical(spec["y"], ds["y"])
    xr.testing.assert_identical(spec["u"], dft(u))
    assert spec.attrs == ds.attrs
    back = idft(spec)
    _assert_round_trip(ds["u"], back["u"])


@pytest.mark.parametrize(
    "time,match",
    [
        (np.array([0.0, 0.1, 0.25, 0.3]), "not evenly spaced"),
        (np.array([0.0, 0.0, 0.0, 0.0]), "strictly increasing"),
        (np.array([0.3, 0.2, 0.1, 0.0]), "strictly increasing"),
    ],
)
def test_dft_refuses_bad_spacing(time, match):
    x = xr.DataArray(np.ones(4), dims="time", coords={"time": time})
    with pytest.raises(ValueError, match=match):
        dft(x)



@pytest.mark.parametrize("kind", ["timedelta64", "datetime64"])
def test_dft_refuses_time_types_and_the_remedy_gives_seconds(kind):
    """numpy counts timedelta64 as a number, so a timedelta64 time coordinate passed the
    check that refuses datetime64: in microseconds it failed inside float() (TypeError), in
    nanoseconds it was read in ns as seconds (bins 1.25e-7 'Hz' for 1 ms samples, silently).
    The time coordinates are seconds (docs/conventions.md): both types are refused with the
    conversion to seconds, which gives the spectrum of the same samples."""
    stamps = np.datetime64("2020-01-01T00:00:00", "ns") + np.arange(8) * np.timedelta64(1, "ms")
    time = stamps - stamps[0] if kind == "timedelta64" else stamps
    x = xr.DataArray(np.sin(np.arange(8.0)), dims="time", coords={"time": time}, name="r")
    with pytest.raises(ValueError, match=rf"coordinate 'time' is {kind}.*seconds.*"
                                         r"x = x.assign_coords\(time=") as info:
        dft(x)
    remedy = str(info.value).split("x = ", 1)[1].rstrip(".")
    fixed = eval(remedy, {"x": x})  # the message's own remedy
    want = dft(x.assign_coords(time=np.arange(8) * 1e-3))
    got = dft(fixed)
    np.testing.assert_array_equal(got.values, want.values)
    np.testing.assert_allclose(got.frequency.values, want.frequency.values, rtol=1e-12)

def test_dft_refuses_missing_coordinate_and_chunked_dim():
    with pytest.raises(ValueError, match="no coordinate"):
        dft(xr.DataArray(np.ones(4), dims="time"))
    chunked = _signal(12).chunk({"time": 5})
    with pytest.raises(ValueError, match=r"\.chunk\(\{'time': -1\}\)"):
        dft(chunked)


def test_dft_idft_and_fast_spectrum_stay_lazy():
    n, factor = 12, 3
    x = xr.DataArray(_exploding((4, n), (1, n)), dims=("e", "time"),
                     coords={"time": np.arange(n) * 0.1})
    spec = dft(x)
    assert dask.is_dask_collection(spec.data)
    assert dask.is_dask_collection(idft(spec).data)
    assert dask.is_dask_collection(idft(dft(x, one_sided=True)).data)
    slow = dft(lift(x, factor), dim="slow_time")
    assert dask.is_dask_collection(slow.data)
    assert dask.is_dask_collection(fast_spectrum_from_lifted(slow).data)


@settings(deadline=None, max_examples=25)
@given(m=st.integers(2, 8), factor=st.integers(1, 4), seed=st.integers(0, 1000),
       complex_=st.booleans())
def test_fast_spectrum_from_lifted_identity(m, factor, seed, complex_):
    x = _signal(m * factor, th=1e-2, extra=[("input", 2)], seed=seed, complex_=complex_)
    fast = dft(x)
    rebuilt = fast_spectrum_from_lifted(dft(lift(x, factor), dim="slow_time"))
    assert rebuilt.dims == fast.dims
    xr.testing.assert_allclose(rebuilt, fast, rtol=1e-10, atol=1e-11)
    # the rebuilt spectrum carries what idft needs
    back = idft(rebuilt)
    np.testing.assert_allclose(back.values, x.values, atol=1e-12)
    np.testing.assert_allclose(back.time.values, x.time.values, rtol=1e-12, atol=1e-15)


def test_fast_spectrum_from_lifted_errors():
    slow = dft(lift(_signal(12), 3), dim="slow_time")
    with pytest.raises(ValueError, match="does not match the 3 lifting phases"):
        fast_spectrum_from_lifted(slow, factor=2)
    with pytest.raises(ValueError, match="need dims"):
        fast_spectrum_from_lifted(dft(_signal(12)))
    with pytest.raises(ValueError, match="one-sided"):
        fast_spectrum_from_lifted(dft(lift(_signal(12), 3), dim="slow_time", one_sided=True))


@pytest.mark.parametrize("select", [[0, 1], slice(0, 3), [1, 0, 2, 3], [3, 2, 1, 0]],
                         ids=["first two", "first three", "swapped", "reversed"])
def test_selected_or_reordered_phases_are_refused(select):
    """``unlift`` and ``fast_spectrum_from_lifted`` read position ``j`` of ``lift_phase`` as
    phase ``j`` of a lifting by its length.  The first phases of a lifting by 4
    (``isel(lift_phase=[0, 1])``, labels 0..1 in order) came out as a signal lifted by 2:
    samples 0, 1, 4, 5, ... on uneven times, and a fast spectrum on a wrong grid; a
    reordered selection gave fast_spectrum_from_lifted a wrong spectrum (unlift refused
    it).  Both are refused now; the whole lifting still round-trips."""
    x = _signal(24, th=0.1, extra=[("input", 2)])
    lifted = lift(x, 4)
    slow = dft(lifted, dim="slow_time")
    for call in (lambda: unlift(lifted.isel(lift_phase=select)),
                 lambda: unlift(lifted.to_dataset(name="x").isel(lift_phase=select)),
                 lambda: fast_spectrum_from_lifted(slow.isel(lift_phase=select))):
        with pytest.raises(ValueError, match="lift_phase") as info:
            call()
        assert "every phase" in str(info.value) or "of the 4 phases" in str(info.value)
    xr.testing.assert_identical(unlift(lifted), x)
    xr.testing.assert_allclose(fast_spectrum_from_lifted(slow), dft(x), rtol=1e-12, atol=1e-12)
    # a lifted array built by hand (no lift_factor) is read as a whole lifting
    bare = xr.DataArray(np.arange(8.0).reshape(4, 2), dims=("slow_time", "lift_phase"))
    assert unlift(bare).values.tolist() == list(range(8))


def test_recorded_lift_factor_is_read_as_one_whole_number():
    """The recorded lift_factor was read with int(): a one-element array (as a file may give
    an attribute back) warned (numpy's deprecated array-to-scalar conversion), and "two" or
    [2, 2] failed inside int(); now the array is read, anything else refused by name."""
    import warnings

    x = xr.DataArray(np.arange(12.0), dims="time",
                     coords={"time": ("time", np.arange(12) * 0.5, {"units": "s"})})
    lifted = lift(x, 2)

    def with_factor(value):
        return lifted.assign_coords(lift_phase=lifted.lift_phase.assign_attrs(lift_factor=value))

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for good in (np.array([2]), np.array([[2.0]]), np.int32(2), 2.0):
            xr.testing.assert_identical(unlift(with_factor(good)), x)
            fast_spectrum_from_lifted(dft(with_factor(good), dim="slow_time"))
        with pytest.raises(ValueError, match="holds 2 of the 4 phases"):
            unlift(with_factor(np.array([4])))
    for bad in ("two", 2.5, np.array([2, 2]), True, 0, np.nan):
        for call in (lambda: unlift(with_factor(bad)),
                     lambda: fast_spectrum_from_lifted(dft(with_factor(bad), dim="slow_time"))):
            with pytest.raises(ValueError, match=r"'lift_phase' coordinate's attribute 'lift_factor' is .*"
                                                 r"not a lifting factor.*assign_attrs\(lift_factor=2\)"):
                call()


@pytest.mark.parametrize("units,scale", [("ms", 1e-3), ("us", 1e-6), ("min", 60.0)])
def test_dft_refuses_a_time_coordinate_in_other_units(units, scale):
    """A time coordinate declared in ms (or us, min) was read as seconds: the frequencies
    came out off by the factor, without a word.  Refused, with the conversion; the same
    coordinate converted to seconds gives the right bins.  Other dims keep their units."""
    x = _signal(16, th=0.5)
    other = x.assign_coords(time=(x.time / scale).assign_attrs(units=units))
    with pytest.raises(ValueError, match=rf"'time' is in '{units}'.*seconds.*factor {re.escape(f'{1 / scale:g}')}"):
        dft(other)
    converted = other.assign_coords(time=(other["time"] * scale).assign_attrs(units="s"))
    np.testing.assert_allclose(dft(converted).frequency.values, np.arange(16) / (16 * 0.5))
    space = xr.DataArray(np.ones(4), dims="x", coords={"x": ("x", np.arange(4.0), {"units": "m"})})
    assert dft(space, dim="x").sizes["freq_x"] == 4


def test_dft_identify_and_validate_experiment_say_the_same_of_nan():
    """One message builder (lcmr_xr.transforms._finite) for dft, identify's lazy guard and
    validate_experiment: the same samples, range and indices for the same bad value (there
    were three builders, counting samples or values, with or without the indices)."""
    import lcmr_xr
    from lcmr_xr import hdd

    ds = hdd.simulate(n_samples=400, noise=False, seed=0)
    ds["y"] = ds.y.copy(data=np.where(np.arange(200)[:, None] == 20, np.nan, ds.y.values))
    t = float(ds.slow_time.values[20])
    said = "1 NaN or inf value(s)"
    tail = f"at 1 of its 200 slow_time samples, from slow_time = {t:.6g} s to {t:.6g} s (indices 20..20)"
    messages = []
    for call in (lambda: lcmr_xr.dft(ds.y, dim="slow_time"),
                 lambda: lcmr_xr.validate_experiment(ds),
                 lambda: lcmr_xr.identify(ds.chunk({"time": 200}), window=12,
                                          degrees=(2, 2, 2)).P.compute()):
        with pytest.raises(ValueError) as info:
            call()
        messages.append(str(info.value))
    for message in messages:
        assert f"y contains {said}" in message and tail in message, message
        assert "interpolate_na('slow_time')" in message, message
