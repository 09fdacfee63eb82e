"""The eager path fits the local models in blocks of slow bins and keeps per bin only what
the finishing steps read (``kernels.identification._fit_blocks``, ``BLOCK_BYTES``); its
results are those of one fit over all bins.  Blocks are forced small here (16 bins, the
restart interval of window 30), so that many blocks, their edges, the circular halo at
bins 0 and M-1 and the mirrored half spectrum are exercised."""

import numpy as np
import pytest

from lcmr_xr import hdd
from lcmr_xr.kernels import identification as ki
from lcmr_xr.kernels.adaptive import denominator_bias
from lcmr_xr.kernels.local_models import fits_half, local_model

WINDOW = 30


@pytest.fixture(scope="module")
def record():
    exp = hdd.simulate(n_samples=1200, seed=3)
    factor = int(exp.attrs["factor"])
    R, Z = ki.experiment_spectra(exp.r.values, exp.u.values, exp.y.values, factor=factor)
    return R, Z, dict(n_fast=exp.sizes["time"], factor=factor, nu=exp.sizes["input"])


def _force_blocks(monkeypatch, nbytes):
    """Set the block size; return the list that collects the bins of every block fitted."""
    calls = []
    real = ki.local_model

    def spy(*args, **kwargs):
        if kwargs.get("bins") is not None:
            calls.append(kwargs["bins"])
        return real(*args, **kwargs)

    monkeypatch.setattr(ki, "local_model", spy)
    monkeypatch.setattr(ki, "BLOCK_BYTES", nbytes)
    return calls


def _assert_same(got: dict, want: dict, names=None):
    names = sorted(want) if names is None else names
    for name in names:
        a, b = np.asarray(got[name]), np.asarray(want[name])
        assert a.shape == b.shape, name
        if a.dtype.kind == "b":
            np.testing.assert_array_equal(a, b, err_msg=name)
        else:
            np.testing.assert_allclose(a, b, rtol=1e-12, atol=0, equal_nan=True, err_msg=name)


def _run(monkeypatch, nbytes, fn, *args, **kwargs):
    calls = _force_blocks(monkeypatch, nbytes)
    out = fn(*args, **kwargs)
    monkeypatch.undo()
    return out, calls


@pytest.mark.parametrize("real", [True, False], ids=["real-mirrored", "complex-every-bin"])
def test_blocks_equal_one_fit_over_all_bins(monkeypatch, record, real):
    R, Z, shape = record
    if not real:  # not conjugate-symmetric: every bin is fitted, no mirror
        R, Z = R * np.exp(0.3j), Z * np.exp(0.3j)
    m = R.shape[-2]
    assert fits_half(R, Z, half_width=WINDOW) is real
    kw = dict(half_width=WINDOW, degrees=(3, 3, 3), **shape)
    small, calls = _run(monkeypatch, 1, ki.identify_spectra, R, Z, **kw)
    whole, one = _run(monkeypatch, 1 << 60, ki.identify_spectra, R, Z, **kw)
    # 16-bin blocks, back to back from bin 0; real signals: up to M/2 (rounded up to the
    # restart grid), complex ones: every bin, the last block ending at M
    last = -(-(m // 2 + 1) // 16) * 16 if real else m
    assert len(calls) == -(-last // 16) > 10 and len(one) == 1
    assert calls[0][0] == 0 and calls[-1][1] == last
    assert all(a[1] == b[0] and (a[1] - a[0]) == 16 for a, b in zip(calls[:-1], calls[1:]))
    _assert_same(small, whole)
    # ... and to the whole-circle pipeline: one local model over all bins (mirrored by the
    # kernel for real signals), its full G_cov, then recover_frf
    fit = local_model(R, Z, half_width=WINDOW, degrees=(3, 3, 3))
    # (with its noise covariance: the bins where cov(P_1) is not a covariance are mended)
    ref = ki.recover_frf(fit.G, fit.G_cov, ny=Z.shape[-1] - R.shape[-1], ill_posed=fit.ill_posed,
                         dof=fit.dof, neighbourhood=True, noise_covariance=fit.noise_covariance,
                         **shape)
    ref.update(G=fit.G, T=fit.T, noise_variance=fit.noise_variance, condition=fit.condition,
               ill_posed=fit.ill_posed,
               G_var=np.real(np.diagonal(fit.G_cov, axis1=-2, axis2=-1)).reshape(fit.G.shape))
    _assert_same(small, ref)
    assert np.isfinite(small["P_var"]).mean() > 0.5  # a real test: bands where determined


def test_auto_window_blocks_equal_one_fit(monkeypatch, record):
    R, Z, shape = record
    kw = dict(windows=(12, 19, 30), degrees=(3, 3, 3), **shape)
    small, calls = _run(monkeypatch, 1, ki.identify_spectra_auto, R, Z, **kw)
    whole, _ = _run(monkeypatch, 1 << 60, ki.identify_spectra_auto, R, Z, **kw)
    assert {b - a for a, b in calls} >= {8, 16}  # each candidate on its own restart grid
    _assert_same(small, whole)
    assert set(np.unique(small["window"])) > {12}


def test_pooled_blocks_equal_one_fit(monkeypatch):
    """Pooled experiments with instruments, the split-half spread and its calibration
    (applied to the reduced terms) and a known noise covariance."""
    exps = [hdd.simulate(n_samples=600, seed=s) for s in range(4)]
    factor = int(exps[0].attrs["factor"])
    spectra = [ki.experiment_spectra(e.r.values, e.u.values, e.y.values, factor=factor)
               for e in exps]
    R = np.stack([s[0] for s in spectra])
    Z = np.stack([s[1] for s in spectra])
    noise = np.abs(Z[0])[:, :, None] * np.abs(Z[1])[:, None, :] * 1e-4 + 0j  # (M, nz, nz)
    shape = dict(n_fast=exps[0].sizes["time"], factor=factor, nu=exps[0].sizes["input"])
    kw = dict(half_width=20, degrees=(3, 3, 3), experiment_axis=-3, denominator="iv", **shape)
    for extra in ({}, {"noise_covariance": noise}):
        small, calls = _run(monkeypatch, 1, ki.identify_spectra, R, Z, **kw, **extra)
        whole, _ = _run(monkeypatch, 1 << 60, ki.identify_spectra, R, Z, **kw, **extra)
        assert len(calls) > 5
        _assert_same(small, whole)
        assert np.any(small["spread_calibration"] > 1)


def test_local_model_bins_are_those_of_the_whole_fit(record):
    """``bins=``: aligned blocks give the whole fit's values bit for bit (bins 0..M/2 of
    real signals, where the whole fit fits them; every bin otherwise, including the blocks
    whose windows wrap around bins 0 and M-1); an unaligned block agrees to rounding."""
    R, Z, _ = record
    m = R.shape[-2]
    for real in (True, False):
        Rx, Zx = (R, Z) if real else (R * 1j ** 0.5, Z * 1j ** 0.5)
        whole = local_model(Rx, Zx, half_width=WINDOW)
        blocks = [(0, 48), (m // 2 - 15, m // 2 + 1)] if real else [(0, 32), (m - 40, m), (16, m)]
        for a, b in blocks:
            part = local_model(Rx, Zx, half_width=WINDOW, bins=(a, b))
            for name in ("G", "T", "noise_covariance", "G_cov", "condition", "ill_posed"):
                if a % 16 == 0 and (b % 16 == 0 or b == m or real):
                    np.testing.assert_array_equal(getattr(part, name), getattr(whole, name)[a:b],
                                                  err_msg=f"{name} {(a, b)}")
                else:  # the recurrence's rounding: relative to the largest of its kind
                    want = np.asarray(getattr(whole, name)[a:b], dtype=complex)
                    np.testing.assert_allclose(getattr(part, name), want, rtol=1e-6,
                                               atol=1e-9 * np.max(np.abs(want)),
                                               err_msg=f"{name} {(a, b)}")
    with pytest.raises(ValueError, match="0 <= start < stop"):
        local_model(R, Z, half_width=WINDOW, bins=(10, m + 1))
    with pytest.raises(ValueError, match="circular=False"):
        local_model(R, Z, half_width=WINDOW, bins=(0, 10), circular=False)
    bad = Z.copy()
    bad[m - 1, 0] = np.nan  # in the halo of bins 0..: checked; far from bins 100..200: not read
    with pytest.raises(ValueError, match="finite"):
        local_model(R, bad, half_width=WINDOW, bins=(0, 16))
    local_model(R, bad, half_width=WINDOW, bins=(100, 200))


def test_local_model_select_fits_those_bins_only(record):
    """``select=``: the selected bins are the whole fit's, bit for bit in aligned blocks
    (``bins=``, as the eager twin fits them), to rounding over the whole circle (nothing is
    mirrored) and non-circular; the others NaN and flagged as not fitted."""
    R, Z, _ = record
    m = R.shape[-2]
    select = ki.twin_bins(m)
    assert select.sum() < 0.55 * m and np.array_equal(select[1:], select[:0:-1])
    whole = local_model(R, Z, half_width=WINDOW)
    fits = {(0, m): local_model(R, Z, half_width=WINDOW, select=select)}
    for a, b in [(0, 48), (m // 2 - 15 - (m // 2 - 15) % 16, m // 2 + 1)]:
        fits[a, b] = local_model(R, Z, half_width=WINDOW, bins=(a, b), select=select)
    for (a, b), part in fits.items():
        sel = select[a:b]
        for name in ("G", "T", "noise_covariance", "G_cov", "condition", "ill_posed"):
            got, want = getattr(part, name)[sel], getattr(whole, name)[a:b][sel]
            if (a, b) != (0, m):
                np.testing.assert_array_equal(got, want, err_msg=f"{name} {(a, b)}")
            else:  # the recurrence's rounding: relative to the largest of its kind
                want = np.asarray(want, dtype=complex)
                np.testing.assert_allclose(got, want, rtol=1e-6,
                                           atol=1e-9 * np.max(np.abs(want)), err_msg=name)
        assert np.all(np.isnan(part.G[~sel])) and np.all(part.ill_posed[~sel])
        assert np.all(np.isinf(part.condition[~sel]))
    # not circular: the bins with a full window among those selected (to rounding)
    flat = local_model(R, Z, half_width=WINDOW, circular=False, select=select)
    full = local_model(R, Z, half_width=WINDOW, circular=False)
    fitted = np.isfinite(flat.condition)
    assert np.array_equal(fitted, select & np.isfinite(full.condition))
    np.testing.assert_allclose(flat.G[fitted], full.G[fitted], rtol=1e-6,
                               atol=1e-9 * np.max(np.abs(full.G[fitted])))
    with pytest.raises(ValueError, match="select must have shape"):
        local_model(R, Z, half_width=WINDOW, select=select[1:])


def test_auto_fits_the_twin_at_every_third_slow_bin(monkeypatch, record):
    """window='auto' fits its Hausman twin (the IV fit of the widest window) at the slow bins
    of ``twin_bins`` only, every ``TWIN_STRIDE``-th of bins 0..M/2 (the others mirrored),
    and its term is the mean of the finite terms within +-6 fast bins."""
    R, Z, kw = record
    m = R.shape[-2]
    seen = []
    real = ki.local_model

    def spy(*args, **kwargs):
        fit = real(*args, **kwargs)
        if kwargs.get("instruments") is not None:
            seen.append((kwargs["bins"], np.isfinite(fit.condition)))
        return fit

    monkeypatch.setattr(ki, "local_model", spy)
    out = ki.identify_spectra_auto(R, Z, windows=(12, 19, WINDOW), degrees=(3, 3, 3), **kw)
    assert seen and ki.TWIN_STRIDE == 3
    half = m // 2 + 1
    fitted = np.zeros(half, bool)
    for (a, b), f in seen:
        fitted[a:min(b, half)] = f[:max(0, min(b, half) - a)]
    want = np.arange(half) % 3 == 0
    assert np.array_equal(fitted & ~want, np.zeros(half, bool))  # only where selected
    assert fitted.sum() >= 0.9 * want.sum() and want.sum() <= half // 3 + 1
    assert np.array_equal(ki.twin_bins(m)[:half], want)
    assert np.array_equal(ki.twin_bins(m)[half:], want[(m - 1) // 2:0:-1])
    # the +-6 fast bins around every fast bin hold 4-5 fitted ones (13 with every bin)
    k = out["P_bias"].shape[-3]
    on = ki.twin_bins(m)[np.arange(-6, k + 6) % m].astype(int)
    per_mean = np.convolve(on, np.ones(13, int), mode="valid")
    assert per_mean.shape == (k,) and per_mean.min() >= 4 and per_mean.max() <= 5


def _old_auto(R, Z, windows, **kw):
    """``window="auto"`` as it was before the refits: every candidate finished whole (one
    block over all bins), then gathered bin by bin (``_choose_windows``, which
    ``finish_packed_auto`` still runs on the frequency-chunked fits)."""
    # (each candidate's own test: the neighbourhood's is the widest one's, _finish_choice)
    outs = [ki.identify_spectra(R, Z, half_width=w, neighbourhood=False, **kw) for w in windows]
    twin = None  # the least-squares denominator's bias from the widest window's IV fit
    n_exp = ki._n_experiments(R, Z, kw.get("experiment_axis"))
    if ki.checks_denominator_bias(kw.get("denominator", "ls"), kw["degrees"],
                                  kw.get("closed_loop", "indirect"), n_exp,
                                  known_noise=kw.get("noise_covariance") is not None):
        zhat = ki.denominator_instruments(R, Z, degrees=kw["degrees"], half_width=windows[-1])
        iv = ki._fit_and_finish(R, Z, half_width=windows[-1], covariance=True, n_exp=n_exp,
                                ny=Z.shape[-1] - R.shape[-1], denominator="iv",
                                instruments=zhat, experiment_axis=kw.get("experiment_axis"),
                                noise_covariance=None, closed_loop="indirect",
                                **{k: kw[k] for k in ("degrees", "n_fast", "factor", "nu")})
        # fitted at the slow bins of twin_bins only: the whole fit there, NaN elsewhere
        m, n_fast = R.shape[-2], kw["n_fast"]
        fitted = ki.twin_bins(m)[np.arange(n_fast // 2 + 1) % m][:, None, None]
        twin = denominator_bias(outs[-1]["P"], np.where(fitted, iv["P"], np.nan),
                                outs[-1]["P_var_linear"],
                                np.where(fitted, iv["P_var_linear"], np.nan),
                                determined=np.isfinite(outs[-1]["P_var"]))
    return ki._choose_windows(outs, np.asarray(windows), R.shape[-2], twin=twin,
                              nr=R.shape[-1], degrees=kw["degrees"], n_exp=n_exp,
                              known_noise=kw.get("noise_covariance") is not None)


def _assert_identical(got: dict, want: dict):
    assert sorted(got) == sorted(want)
    for name in want:
        a, b = np.asarray(got[name]), np.asarray(want[name])
        assert a.dtype == b.dtype and a.shape == b.shape, name
        np.testing.assert_array_equal(a, b, err_msg=name)  # bit for bit (NaN where NaN)


@pytest.fixture(scope="module")
def pooled_spectra():
    exps = [hdd.simulate(n_samples=600, seed=s) for s in range(4)]
    factor = int(exps[0].attrs["factor"])
    spectra = [ki.experiment_spectra(e.r.values, e.u.values, e.y.values, factor=factor)
               for e in exps]
    shape = dict(n_fast=exps[0].sizes["time"], factor=factor, nu=exps[0].sizes["input"])
    return np.stack([s[0] for s in spectra]), np.stack([s[1] for s in spectra]), shape


def _auto_case(case, record, pooled_spectra):
    """``(R, Z, windows, keywords)`` of one setting of ``window="auto"``."""
    R, Z, shape = record
    windows, kw = (12, 19, 30), dict(degrees=(3, 3, 3), **shape)
    if case == "complex":  # every bin fitted, no mirror
        R, Z = R * np.exp(0.3j), Z * np.exp(0.3j)
    elif case == "lpm":
        kw["degrees"] = (3, 3, 0)
    elif case == "iv":
        kw["denominator"] = "iv"
    elif case == "direct":
        exp = hdd.simulate(n_samples=1200, seed=3)
        R, Z = ki.experiment_spectra(exp.r.values, exp.u.values, exp.y.values,
                                     factor=shape["factor"], closed_loop="direct")
        kw["closed_loop"] = "direct"
    elif case in ("stacked", "pooled"):
        R, Z, shape = pooled_spectra
        kw.update(shape)
        if case == "pooled":  # IV, split-half calibration, a known noise not mirrored
            m, nz = Z.shape[-2:]
            rng = np.random.default_rng(1)
            A = rng.standard_normal((m, nz, nz)) + 1j * rng.standard_normal((m, nz, nz))
            noise = (A @ A.conj().swapaxes(-1, -2)) * (np.abs(Z[0])[:, :, None]
                                                       * np.abs(Z[0])[:, None, :] * 1e-4)
            windows = (8, 13, 20)
            kw.update(experiment_axis=-3, denominator="iv", noise_covariance=noise)
    return R, Z, windows, kw


@pytest.mark.parametrize("case", ["real", "complex", "lpm", "iv", "direct", "stacked", "pooled"])
def test_auto_refits_are_the_candidates_first_fits_bit_for_bit(monkeypatch, record,
                                                               pooled_spectra, case):
    """``window="auto"`` keeps of the narrower candidates only what the choice reads and fits
    the bins they win again (``_refit_chosen``, in 16-bin blocks here): every output is
    that of finishing every candidate whole in one block and gathering, bit for bit;
    likewise when the narrower candidates are held whole (short records) or only the
    first is."""
    R, Z, windows, kw = _auto_case(case, record, pooled_spectra)
    monkeypatch.setattr(ki, "BLOCK_BYTES", 1 << 60)
    want = _old_auto(R, Z, windows, **kw)
    monkeypatch.setattr(ki, "HELD_BYTES", 1 << 60)
    _assert_identical(ki.identify_spectra_auto(R, Z, windows=windows, **kw), want)
    first = sum(v.nbytes for k, v in ki.identify_spectra(R, Z, half_width=windows[0], **kw).items()
                if k not in ki._FAST)
    fits, refits = [], []  # (refit?, half_width, bins) of every block fitted; refitted windows
    real_fit, real_refit = ki._fit_terms, ki._refit_chosen

    def fit(*args, **kwargs):
        fits.append((bool(refits) and refits[-1] is not None, kwargs["half_width"],
                     kwargs["bins"]))
        return real_fit(*args, **kwargs)

    def refit(*args, **kwargs):
        refits.append(kwargs["half_width"])
        real_refit(*args, **kwargs)
        refits.append(None)

    monkeypatch.setattr(ki, "_fit_terms", fit)
    monkeypatch.setattr(ki, "_refit_chosen", refit)
    monkeypatch.setattr(ki, "BLOCK_BYTES", 1)  # blocks of one restart interval
    m = R.shape[-2]
    for held, refitted in ((0, windows[:-1]), (first, windows[1:-1])):
        fits.clear()
        refits.clear()
        monkeypatch.setattr(ki, "HELD_BYTES", held)
        got = ki.identify_spectra_auto(R, Z, windows=windows, **kw)
        _assert_identical(got, want)
        assert [w for w in refits if w is not None] == list(refitted)
        assert all(np.any(got["window"] == w) for w in windows)  # each candidate wins bins
        for w in refitted:  # fewer bins than the first fit, in blocks on the restart grid
            align = 1 << (w.bit_length() - 1)
            again = [b for r, n, b in fits if r and n == w]
            first_fit = [b for r, n, b in fits if not r and n == w]
            records = got["window"][..., 0].size  # refitted record by record
            assert 0 < sum(b - a for a, b in again) < records * sum(b - a for a, b in first_fit)
            assert all(a % align == 0 and (b % align == 0 or b == m) for a, b in again)
            # every bin the window won is in a refitted block (or its mirror M - k is)
            bins = np.zeros(m, dtype=bool)
            for a, b in again:
                bins[a:b] = True
            won = np.flatnonzero(np.any(got["window"] == w, axis=tuple(range(got["window"].ndim - 1))))
            assert np.all(bins[won] | bins[(m - won) % m])


def test_auto_refit_runs_on_the_restart_grid():
    need = np.zeros(100, dtype=bool)
    need[[3, 17, 18, 40, 99]] = True
    # blocks 0..32, 32..64, 64..100 (the last ends at M), restart interval 8
    assert ki._chosen_runs(need, [0, 32, 64, 100], 8) == [(0, 8), (16, 24), (40, 48), (96, 100)]
    need[:] = False
    assert ki._chosen_runs(need, [0, 32, 64, 100], 8) == []
    need[30:34] = True  # runs do not cross a block's edge
    assert ki._chosen_runs(need, [0, 32, 64, 100], 8) == [(24, 32), (32, 40)]
    need[:] = False
    need[[66, 80, 90, 97]] = True  # within a block, consecutive intervals make one run
    assert ki._chosen_runs(need, [0, 32, 64, 100], 8) == [(64, 72), (80, 100)]


def test_frf_variance_at_some_fast_bins_is_the_whole_calls():
    """``frf_variance_from_first_row`` at a subset of fast bins (the twin's) reads only
    their slow bins: the values of the call at every bin there, bit for bit."""
    from lcmr_xr.kernels.closed_loop import frf_variance_from_first_row

    rng = np.random.default_rng(1)
    m, f, ny, nu = 20, 3, 2, 1
    a = rng.standard_normal((m, ny * f * nu, 7)) + 1j * rng.standard_normal((m, ny * f * nu, 7))
    cov = a @ a.conj().swapaxes(-1, -2)
    every = np.arange(m * f // 2 + 1)
    whole = frf_variance_from_first_row(cov, m * f, f, every, ny, nu)
    some = every[ki.twin_bins(m)[every % m]]
    got = frf_variance_from_first_row(cov, m * f, f, some, ny, nu)
    assert got.shape == (some.size, ny, nu) and np.all(whole > 0)
    np.testing.assert_array_equal(got, whole[some])
