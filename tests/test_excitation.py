"""Multisine kernels and the labelled multisine generators."""

from __future__ import annotations

import numpy as np
import pytest
import xarray as xr
from hypothesis import given, settings
from hypothesis import strategies as st

from lcmr_xr.excitation import bins_for_band, multisine, orthogonal_multisines
from lcmr_xr.hdd import disturbances as hdd_disturbances
from lcmr_xr.kernels import excitation as ke


@st.composite
def designs(draw):
    n = draw(st.integers(4, 80))
    half = n // 2
    bins = draw(st.lists(st.integers(1, half), min_size=1, max_size=half, unique=True))
    channels = draw(st.integers(1, 3))
    rms = draw(st.lists(st.floats(1e-3, 1e3), min_size=channels, max_size=channels))
    seed = draw(st.integers(0, 2**32 - 1))
    return n, np.array(bins), channels, np.array(rms), seed


@settings(deadline=None, max_examples=60)
@given(designs())
def test_random_phase_multisine_spectrum_and_rms(design):
    n, bins, c, rms, seed = design
    x = ke.random_phase_multisine(n, c, bins, rms, np.random.default_rng(seed))
    assert x.shape == (n, c) and x.dtype == float
    np.testing.assert_allclose(np.sqrt(np.mean(x**2, axis=0)), rms, rtol=1e-12)
    spectrum = np.abs(np.fft.fft(x, axis=0))
    excited = np.zeros(n, bool)
    excited[bins] = True
    excited[(n - bins) % n] = True  # mirror bins of a real signal
    for ch in range(c):
        level = spectrum[bins[0], ch]
        np.testing.assert_allclose(spectrum[excited, ch], level, rtol=1e-9)
        assert np.all(spectrum[~excited, ch] <= 1e-12 * level)  # includes DC


def test_nyquist_bin_is_real_with_both_signs_over_seeds():
    n = 16
    signs = set()
    for seed in range(20):
        x = ke.random_phase_multisine(n, 1, [3, 8], 1.0, np.random.default_rng(seed))
        nyq = np.fft.fft(x[:, 0])[8]
        assert abs(nyq.imag) <= 1e-12 * abs(nyq)
        signs.add(np.sign(nyq.real))
        np.testing.assert_allclose(abs(nyq), abs(np.fft.fft(x[:, 0])[3]), rtol=1e-12)
    assert signs == {-1.0, 1.0}


def test_seed_reproducible_and_channels_independent():
    a = ke.random_phase_multisine(64, 2, np.arange(1, 20), 1.0, np.random.default_rng(7))
    b = ke.random_phase_multisine(64, 2, np.arange(1, 20), 1.0, np.random.default_rng(7))
    c = ke.random_phase_multisine(64, 2, np.arange(1, 20), 1.0, np.random.default_rng(8))
    np.testing.assert_array_equal(a, b)
    assert not np.allclose(a, c)
    assert not np.allclose(a[:, 0], a[:, 1])


@pytest.mark.parametrize(
    "bins,match",
    [
        ([0, 1], r"outside 1\.\.8"),
        ([9], r"outside 1\.\.8"),
        ([2, 2], "duplicates"),
        ([], "non-empty"),
        ([1.5], "integers"),
    ],
)
def test_bad_bins_refused(bins, match):
    with pytest.raises(ValueError, match=match):
        ke.random_phase_multisine(16, 1, bins, 1.0, np.random.default_rng(0))


def test_bad_rms_and_rng_refused():
    with pytest.raises(ValueError, match=r"one value per channel \(shape \(2,\)\)"):
        ke.random_phase_multisine(16, 2, [1], [1.0, 2.0, 3.0], np.random.default_rng(0))
    with pytest.raises(ValueError, match="finite and positive"):
        ke.random_phase_multisine(16, 1, [1], 0.0, np.random.default_rng(0))
    with pytest.raises(TypeError, match="default_rng"):
        ke.random_phase_multisine(16, 1, [1], 1.0, 0)


def test_crest_factor_known_signals():
    n = 64
    square = np.where(np.arange(n) < n // 2, 1.0, -1.0)
    sine = np.sin(2 * np.pi * 3 * np.arange(n) / n)
    assert ke.crest_factor(square, axis=0) == pytest.approx(1.0)
    assert ke.crest_factor(sine, axis=0) == pytest.approx(np.sqrt(2), rel=1e-12)
    two = ke.crest_factor(np.stack([square, 2 * sine], axis=1), axis=0)
    np.testing.assert_allclose(two, [1.0, np.sqrt(2)], rtol=1e-12)
    assert np.isnan(ke.crest_factor(np.zeros(4), axis=0))


def test_schroeder_crest_factor_below_typical_random():
    n, bins = 1024, np.arange(1, 301)
    schroeder = ke.schroeder_multisine(n, 1, bins, 1.0)
    random_cf = [
        ke.crest_factor(ke.random_phase_multisine(n, 1, bins, 1.0, np.random.default_rng(s)), 0)[0]
        for s in range(30)
    ]
    cf = ke.crest_factor(schroeder, 0)[0]
    assert cf < 2.0  # Schroeder's flat-spectrum design: about 1.6-1.7
    assert cf < np.min(random_cf)  # and below every random draw here (median ~3.4)
    # flat spectrum, exact rms
    spec = np.abs(np.fft.fft(schroeder[:, 0]))
    np.testing.assert_allclose(spec[bins], spec[1], rtol=1e-9)
    assert np.sqrt(np.mean(schroeder**2)) == pytest.approx(1.0, rel=1e-12)


@pytest.mark.parametrize("c", [1, 2, 3, 4])
@pytest.mark.parametrize("with_nyquist", [False, True])
def test_orthogonal_multisines_are_orthogonal_at_every_bin(c, with_nyquist):
    n = 32
    bins = np.arange(1, n // 2 + (1 if with_nyquist else 0))
    rng = np.random.default_rng(c)
    if with_nyquist and c == 3:
        with pytest.raises(ValueError, match="Drop bin 16"):
            ke.orthogonal_random_phase_multisines(n, c, bins, 1.0, rng)
        return
    rms = np.arange(1.0, c + 1)
    u = ke.orthogonal_random_phase_multisines(n, c, bins, rms, rng)
    assert u.shape == (c, n, c)
    np.testing.assert_allclose(np.sqrt(np.mean(u**2, axis=1)), np.broadcast_to(rms, (c, c)), rtol=1e-12)
    spec = np.fft.fft(u, axis=1)  # [e, k, c]
    for k in range(n):
        uk = spec[:, k, :] / rms  # [e, c], unit amplitude per channel
        if k in bins or (n - k) in bins:
            gram = uk.conj().T @ uk
            level = np.abs(uk[0, 0]) ** 2
            np.testing.assert_allclose(np.abs(uk) ** 2, level, rtol=1e-9)  # flat
            np.testing.assert_allclose(gram, c * level * np.eye(c), atol=1e-9 * c * level)
        else:
            assert np.max(np.abs(uk)) <= 1e-12 * np.max(np.abs(spec / rms))


# --- labelled layer ---------------------------------------------------------------


def test_multisine_labels_coords_attrs():
    u = multisine(100, sampling_period=1e-3, rms=[1.0, 2.0], band=(20, 200), periods=3, seed=4,
                  units="V", dim="input")
    assert u.dims == ("time", "input")
    assert u.sizes == {"time": 300, "input": 2}
    np.testing.assert_allclose(u.time.values, np.arange(300) * 1e-3)
    assert u.time.values[0] == 0.0
    assert u.time.attrs["units"] == "s" and u.time.attrs["standard_name"] == "time"
    assert u.input.values.tolist() == ["u0", "u1"]
    assert u.input.attrs["units"] == "1" and "long_name" in u.input.attrs
    assert u.attrs["units"] == "V" and u.attrs["long_name"]
    assert u.attrs["seed"] == 4 and u.attrs["phases"] == "random"
    assert u.attrs["excited_bins"].tolist() == list(range(2, 21))
    np.testing.assert_allclose(u.attrs["band"], [20.0, 200.0])
    assert u.crest_factor.attrs["units"] == "1"
    one = u.isel(time=slice(0, 100)).values
    np.testing.assert_array_equal(u.isel(time=slice(200, 300)).values, one)  # periodic
    np.testing.assert_allclose(u.crest_factor.values, ke.crest_factor(one, axis=0), rtol=1e-12)
    np.testing.assert_allclose(np.sqrt((u**2).mean("time")), [1.0, 2.0], rtol=1e-12)
    # excited exactly on the band, in Hz
    spec = np.abs(np.fft.rfft(one, axis=0))
    freqs = np.fft.rfftfreq(100, 1e-3)
    on = spec[:, 0] > 1e-9 * spec[:, 0].max()
    assert freqs[on].min() == pytest.approx(20) and freqs[on].max() == pytest.approx(200)
    assert on.sum() == 19


def test_multisine_seed_reproducible_and_recorded():
    a = multisine(64, sampling_period=0.1, rms=1.0, seed=11)
    b = multisine(64, sampling_period=0.1, rms=1.0, seed=11)
    xr.testing.assert_identical(a, b)
    fresh = multisine(64, sampling_period=0.1, rms=1.0)
    again = multisine(64, sampling_period=0.1, rms=1.0, seed=fresh.attrs["seed"])
    xr.testing.assert_identical(fresh, again)


def test_multisine_default_bins_and_schroeder():
    u = multisine(64, sampling_period=0.5, rms=1.0, phases="schroeder", channels=["a"])
    spec = np.abs(np.fft.fft(u.values[:, 0]))
    np.testing.assert_allclose(spec[1:], spec[1], rtol=1e-9)  # all bins 1..N-1 (mirrors)
    assert spec[0] < 1e-12
    assert "seed" not in u.attrs and u.attrs["phases"] == "schroeder"
    assert u.channel.values.tolist() == ["a"]


def test_multisine_argument_errors():
    with pytest.raises(ValueError, match="not both"):
        multisine(64, sampling_period=0.1, rms=1.0, band=(1, 2), bins=[1])
    with pytest.raises(ValueError, match="contains no DFT bin"):
        multisine(64, sampling_period=0.1, rms=1.0, band=(0.01, 0.02))
    with pytest.raises(ValueError, match="phases must be one of"):
        multisine(64, sampling_period=0.1, rms=1.0, phases="flat")
    with pytest.raises(ValueError, match="sampling_period"):
        multisine(64, sampling_period=0.0, rms=1.0)
    with pytest.raises(ValueError, match="periods"):
        multisine(64, sampling_period=0.1, rms=1.0, periods=0)


def test_bins_for_band_edges_inclusive():
    assert bins_for_band(100, 0.01, (1.0, 3.0)).tolist() == [1, 2, 3]
    assert bins_for_band(100, 0.01, (0.0, 1e9)).tolist() == list(range(1, 51))


def test_orthogonal_multisines_labelled():
    u = orthogonal_multisines(64, sampling_period=0.01, rms=[1.0, 0.5], channels=["a", "b"],
                              band=(1, 30), periods=2, seed=3)
    assert u.dims == ("experiment", "time", "channel")
    assert u.experiment.values.tolist() == [0, 1]
    assert u.experiment.attrs["units"] == "1"
    assert u.crest_factor.dims == ("experiment", "channel")
    np.testing.assert_allclose(np.sqrt((u.isel(time=slice(0, 64)) ** 2).mean("time")),
                               [[1.0, 0.5], [1.0, 0.5]], rtol=1e-12)
    spec = np.fft.fft(u.isel(time=slice(0, 64)).values, axis=1)
    for k in u.attrs["excited_bins"]:
        uk = spec[:, k, :] / np.array([1.0, 0.5])
        gram = uk.conj().T @ uk
        np.testing.assert_allclose(gram, gram[0, 0].real * np.eye(2), atol=1e-9 * abs(gram[0, 0]))
    again = orthogonal_multisines(64, sampling_period=0.01, rms=[1.0, 0.5], channels=["a", "b"],
                                  band=(1, 30), periods=2, seed=3)
    xr.testing.assert_identical(u, again)


@pytest.mark.parametrize("call", [
    lambda rng: ke.random_phase_multisine(16, 1, [1, 2], 1.0, rng),
    lambda rng: ke.orthogonal_random_phase_multisines(16, 2, [1, 2], 1.0, rng),
    lambda rng: hdd_disturbances.fan_vibration(10, rng),
    lambda rng: hdd_disturbances.rotational_vibration(10, rng),
    lambda rng: hdd_disturbances.repeatable_runout(10, rng),
])
def test_random_signals_refuse_a_seed_in_place_of_a_generator(call):
    with pytest.raises(TypeError, match=r"numpy.random.Generator, got int; pass numpy.random.default_rng"):
        call(3)
    assert np.all(np.isfinite(call(np.random.default_rng(0))))
