"""The main job: identify the bundled dual-stage HDD experiment as the paper does.

``lcmr-xr demo`` (and ``make demo``) runs :func:`run_demo`: load the bundled experiment
(or simulate it when it is missing), identify the VCM and PZT FRFs (LRM, degrees 3, 3, 3 as
in the paper; window chosen per bin, ``window="auto"``), write the FRF NetCDF and Bode
plots, and print how close the estimate is to the exact FRF of the benchmark and how often
its 95 % band holds the truth, per frequency band.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import xarray as xr

from lcmr_xr import conventions as cv
from lcmr_xr.settings import DEFAULT_WINDOW, as_integer

BUNDLED = "hdd_case2_N3600.nc"
#: Files :func:`run_demo` writes into its output directory: the FRF, then the two plots.
OUTPUT_NAMES = ("hdd_frf.nc", "hdd_bode.png", "hdd_pzt_zoom.png")
PZT_ZOOM_HZ = (38000.0, 50400.0)
#: Frequency bands (Hz) of the accuracy table: below the high-loop-gain region's edge,
#: up to the fan vibration, up to half the slow Nyquist frequency... to the fast Nyquist.
BANDS_HZ = ((0.0, 500.0), (500.0, 5000.0), (5000.0, 25200.0), (25200.0, 50400.0))


def find_bundled_experiment(name: str = BUNDLED) -> Path | None:
    """Path of a bundled experiment: ``./datasets/NAME`` or the repository's ``datasets/``."""
    for base in (Path.cwd() / "datasets", Path(__file__).resolve().parent.parent / "datasets"):
        if (base / name).is_file():
            return base / name
    return None


def _check_frf_and_truth(frf, truth, func: str) -> None:
    """An FRF dataset and a truth on exactly its frequencies: ``frf.P - truth`` aligns by
    label, so a truth on other (or rounded) frequencies would silently drop bins from the
    errors while the band counts still count them."""
    if not isinstance(frf, xr.Dataset) or "P" not in frf.data_vars or cv.FREQUENCY not in frf.coords:
        raise TypeError(f"{func} needs the FRF dataset of lcmr_xr.identify (variable P on "
                        f"'frequency'), got {type(frf).__name__}"
                        f"{' without P' if isinstance(frf, xr.Dataset) else ''}.")
    if isinstance(truth, xr.DataArray) and cv.FREQUENCY in truth.dims:
        f = np.asarray(frf[cv.FREQUENCY].values)
        ft = np.asarray(truth[cv.FREQUENCY].values) if cv.FREQUENCY in truth.coords else None
        if ft is None or ft.shape != f.shape or not np.array_equal(ft, f):
            raise ValueError(
                f"{func}: truth must be on the FRF's frequencies ({f.size} bins), but its "
                f"'frequency' has {'no coordinate' if ft is None else f'{ft.size} other values'}; "
                "evaluate it there, e.g. hdd.true_frf(frf.frequency[1:]).reindex("
                "frequency=frf.frequency) (DC is inf for the VCM).")
    elif not (isinstance(truth, np.ndarray) and truth.shape == frf.P.shape):
        raise TypeError(f"{func} needs truth as a DataArray on the FRF's frequency, output and "
                        f"input (or an array of P's shape {frf.P.shape}), got "
                        f"{type(truth).__name__}{getattr(truth, 'shape', '')}.")


def relative_error_table(frf: xr.Dataset, truth: xr.DataArray) -> xr.Dataset:
    """Median relative error ``|P_hat - P| / |P|`` per input, below and above the slow Nyquist frequency.

    Parameters
    ----------
    frf : xarray.Dataset
        Identification result with ``P`` and attribute ``slow_nyquist`` (Hz).
    truth : xarray.DataArray
        Exact FRF on the same ``frequency``, ``output``, ``input``.

    Returns
    -------
    xarray.Dataset
        ``below`` and ``above`` (``output``, ``input``), dimensionless; DC and the fast
        Nyquist bin are left out.
    """
    _check_frf_and_truth(frf, truth, "relative_error_table")
    f = frf[cv.FREQUENCY]
    interior = (f > 0) & (f < f.max())
    rel = (abs(frf.P - truth) / abs(truth)).where(interior)
    nyq = frf.attrs["slow_nyquist"]
    out = xr.Dataset({
        "below": rel.where(f < nyq).median(cv.FREQUENCY),
        "above": rel.where(f > nyq).median(cv.FREQUENCY),
    })
    for name, where in (("below", "below"), ("above", "above")):
        out[name].attrs = {"long_name": f"median relative error {where} the slow Nyquist frequency",
                           "units": "1"}
    return out


def band_median(x: xr.DataArray, slow_nyquist: float, low: float = 500.0) -> xr.DataArray:
    """Median of ``x`` over ``frequency`` in three bands, for the first output.

    The bands are ``(0, low)``, ``[low, slow_nyquist)`` and ``(slow_nyquist, fast
    Nyquist)``; DC and the fast Nyquist bin are left out.  The notebooks use it for
    quick error summaries; :func:`band_table` adds coverage and flags.

    Parameters
    ----------
    x : xarray.DataArray
        Quantity on ``frequency`` (Hz) and ``output`` (and any other dims, kept).
    slow_nyquist : float
        Slow Nyquist frequency in Hz (the FRF's ``slow_nyquist`` attribute).
    low : float, default 500.0
        Upper edge of the lowest band in Hz.

    Returns
    -------
    xarray.DataArray
        The medians on a new ``band`` dim (labels name the bands), first output only.
    """
    f = x[cv.FREQUENCY]
    bands = {
        f"{f[1].item():.0f}-{low:.0f} Hz": (f > 0) & (f < low),
        f"{low:.0f} Hz-slow Nyquist": (f >= low) & (f < slow_nyquist),
        "slow-fast Nyquist": (f > slow_nyquist) & (f < f.max()),
    }
    out = xr.concat([x.where(sel).median(cv.FREQUENCY) for sel in bands.values()],
                    dim=xr.DataArray(list(bands), dims="band", name="band"))
    return out.isel({cv.OUTPUT: 0}, drop=True)


def band_errors(frf: xr.Dataset, truth: xr.DataArray, low: float = 500.0) -> xr.DataArray:
    """Median relative error ``|P_hat - P| / |P|`` per input in the bands of :func:`band_median`.

    Parameters
    ----------
    frf : xarray.Dataset
        Identification result with ``P`` and the attribute ``slow_nyquist``.
    truth : xarray.DataArray
        Exact FRF on the same ``frequency``, ``output``, ``input``.
    low : float, default 500.0
        Upper edge of the lowest band in Hz.

    Returns
    -------
    xarray.DataArray
        Dimensionless medians on (``band``, ``input``, ...).
    """
    _check_frf_and_truth(frf, truth, "band_errors")
    out = band_median(abs(frf.P - truth) / abs(truth), frf.attrs["slow_nyquist"], low)
    return out.assign_attrs(units="1", long_name="median relative error")


def band_table(frf: xr.Dataset, truth: xr.DataArray, bands=BANDS_HZ) -> xr.Dataset:
    """Per frequency band: median relative error, coverage of the 95 % disc, flagged fraction.

    Parameters
    ----------
    frf : xarray.Dataset
        Identification result with ``P``, ``P_std`` and (optionally) ``P_undetermined``.
    truth : xarray.DataArray
        Exact FRF on the same ``frequency``, ``output``, ``input``.
    bands : sequence of (float, float), optional
        Open frequency intervals in Hz; default :data:`BANDS_HZ`.

    Returns
    -------
    xarray.Dataset
        On (``band``, ``output``, ``input``): ``median_error`` (median over the band's
        bins of ``|P_hat - P| / |P|``), ``coverage`` (fraction of bins with
        ``|P_hat - P| <= sqrt(ln 20) P_std``; a bin flagged ``P_undetermined`` has an
        unbounded band and counts as covered), ``flagged`` (fraction flagged), all
        dimensionless.  DC and the fast Nyquist bin are left out.

    Raises
    ------
    TypeError
        ``frf`` not an FRF dataset, ``truth`` neither a DataArray nor an array of P's
        shape, ``bands`` not pairs of numbers.
    ValueError
        ``truth`` on other frequencies than ``frf`` (the difference would align by label
        and drop bins silently), or a band that is not ``0 <= f_lo < f_hi``.
    """
    _check_frf_and_truth(frf, truth, "band_table")
    try:
        bands = [(float(lo), float(hi)) for lo, hi in bands]
    except (TypeError, ValueError):
        raise TypeError(f"bands must be pairs (f_lo, f_hi) in Hz, got {bands!r}; e.g. "
                        f"bands=[(500, 5000)].") from None
    wrong = [b for b in bands if not (0 <= b[0] < b[1])]
    if wrong:
        raise ValueError(f"bands {wrong} are not intervals 0 <= f_lo < f_hi in Hz (an empty band "
                         f"gives NaN rows); e.g. bands=[(500, 5000)].")
    f = frf[cv.FREQUENCY]
    interior = (f > 0) & (f < f.max())
    err = abs(frf.P - truth)
    flagged = frf["P_undetermined"] if "P_undetermined" in frf else xr.zeros_like(f, dtype=bool)
    covered = (err <= np.sqrt(np.log(20.0)) * frf.P_std) | flagged
    rows = []
    for lo, hi in bands:
        sel = interior & (f > lo) & (f < hi)
        rows.append(xr.Dataset({
            "median_error": (err / abs(truth)).where(sel).median(cv.FREQUENCY),
            "coverage": covered.where(sel).sum(cv.FREQUENCY) / sel.sum(),
            "flagged": (flagged.where(sel).sum(cv.FREQUENCY) / sel.sum()) * xr.ones_like(
                err.isel({cv.FREQUENCY: 0}, drop=True), dtype=float),
        }))
    out = xr.concat(rows, dim="band")
    out = out.assign_coords(band=("band", [f"{lo:.0f}-{hi:.0f} Hz" for lo, hi in bands],
                                  {"long_name": "frequency band", "units": "1"}))
    for name, long_name in (("median_error", "median relative error |P_hat - P| / |P|"),
                            ("coverage", "fraction of bins whose 95 % band holds the truth"),
                            ("flagged", "fraction of bins flagged P_undetermined")):
        out[name].attrs = {"long_name": long_name, "units": "1"}
    return out


def resonance_peaks(frf: xr.Dataset, truth: xr.DataArray, *, input: str = "pzt",
                    band=PZT_ZOOM_HZ, count: int = 4, search_bins: int = 3) -> list[tuple[float, float]]:
    """The ``count`` largest resonance peaks of ``|truth|`` in ``band`` and the estimate's peak near each.

    Returns a list of ``(true_hz, estimated_hz)``: the estimate's peak is the largest
    ``|P_hat|`` within ``search_bins`` bins of the true peak.
    """
    count = as_integer(count, "count", minimum=1, example=4)  # 2.5 is refused, not truncated
    search_bins = as_integer(search_bins, "search_bins", minimum=0, example=3)
    f = frf[cv.FREQUENCY].values
    t = np.abs(truth.sel(input=input).isel(output=0).values)
    e = np.abs(frf.P.sel(input=input).isel(output=0).values)
    sel = np.flatnonzero((f >= band[0]) & (f <= band[1]))
    inner = sel[(sel > 0) & (sel < f.size - 1)]
    is_peak = (t[inner] > t[inner - 1]) & (t[inner] >= t[inner + 1])
    peaks = inner[is_peak]
    peaks = peaks[np.argsort(t[peaks])[::-1][:count]]
    out = []
    for k in sorted(peaks):
        lo, hi = max(k - search_bins, 0), min(k + search_bins + 1, f.size)
        k_est = lo + int(np.nanargmax(e[lo:hi]))
        out.append((float(f[k]), float(f[k_est])))
    return out


def output_files(output_dir, *, plot: bool = True) -> list[Path]:
    """The files :func:`run_demo` writes into ``output_dir`` (the FRF; with ``plot``, two PNGs).

    Parameters
    ----------
    output_dir : str or pathlib.Path
        The demo's output directory.
    plot : bool, default True
        Include the Bode plots.

    Returns
    -------
    list of pathlib.Path
    """
    names = OUTPUT_NAMES if plot else OUTPUT_NAMES[:1]
    return [Path(output_dir) / name for name in names]


def run_demo(experiment_path=None, output_dir="demo-output", *, window=DEFAULT_WINDOW,
             degrees=(3, 3, 3), plot: bool = True, echo=print) -> dict:
    """Identify the bundled HDD experiment, write results, print an accuracy summary.

    Parameters
    ----------
    experiment_path : str or pathlib.Path, optional
        Experiment NetCDF file; default the bundled ``datasets/hdd_case2_N3600.nc``
        (simulated with :func:`lcmr_xr.hdd.simulate` if it cannot be found).
    output_dir : str or pathlib.Path, default "demo-output"
        Where ``hdd_frf.nc``, ``hdd_bode.png`` and ``hdd_pzt_zoom.png`` are written.
    window : int or "auto", default "auto"
        Local window half-width (the paper's ``n``, 30), or chosen per bin.
    degrees : (int, int, int), default (3, 3, 3)
        ``(Rn, Rm, Rd)``, the paper's choice.
    plot : bool, default True
        Write the PNG Bode plots.
    echo : callable, default print
        Where the summary lines go.

    Returns
    -------
    dict
        ``frf`` (Dataset), ``errors`` (Dataset of median relative errors), ``bands``
        (Dataset of :func:`band_table`), ``peaks``
        (list of (true Hz, estimated Hz)), ``files`` (paths written), ``seconds``.
    """
    from lcmr_xr import hdd
    from lcmr_xr.identification import identify
    from lcmr_xr.io import open_experiment, save

    out_dir = Path(output_dir)
    path = Path(experiment_path) if experiment_path is not None else find_bundled_experiment()
    if path is None:
        echo("bundled experiment not found; simulating the paper's experiment (seed 0)")
        exp = hdd.simulate(n_samples=3600, case=2, noise=True, seed=0)
    else:
        echo(f"experiment: {path}")
        exp = open_experiment(path)
    t0 = time.perf_counter()
    frf = identify(exp, method="lrm", window=window, degrees=degrees)
    seconds = time.perf_counter() - t0
    case = int(exp.attrs.get("case", 2))
    # the VCM's rigid-body double integrator makes the exact FRF infinite at DC: leave DC out
    truth = hdd.true_frf(frf[cv.FREQUENCY][1:], case=case).reindex({cv.FREQUENCY: frf[cv.FREQUENCY]})
    files = output_files(out_dir, plot=False)
    out_dir.mkdir(parents=True, exist_ok=True)  # only now: a failed run leaves no empty directory
    save(frf, files[0])
    if plot:
        files += _plots(frf, truth, out_dir)
    errors = relative_error_table(frf, truth)
    bands = band_table(frf, truth)
    peaks = resonance_peaks(frf, truth)
    n, f_ = exp.sizes[cv.TIME], exp.attrs[cv.FACTOR]
    if window == "auto":
        chosen = np.unique(frf.local_window.values).tolist()
        what = f"window chosen per bin among {chosen}"
    else:
        what = f"LRM window {window} ({2 * window + 1} bins)"
    echo(f"identified N = {n} fast samples, F = {f_}, {what}, degrees {tuple(degrees)} "
         f"in {seconds:.2f} s")
    echo(f"slow Nyquist frequency: {frf.attrs['slow_nyquist']:.0f} Hz")
    echo("median relative error |P_hat - P| / |P|:")
    echo(f"  {'actuator':<10}{'below slow Nyquist':>20}{'above slow Nyquist':>20}")
    for name in frf[cv.INPUT].values:
        row = errors.sel(input=name).isel(output=0)
        echo(f"  {str(name):<10}{float(row.below):>20.2e}{float(row.above):>20.2e}")
    echo("per band: median relative error, 95 % band holds the truth (flagged bins: unbounded"
         " band, counted as holding it), flagged fraction:")
    echo(f"  {'band':<16}{'VCM error':>11}{'PZT error':>11}{'VCM cover':>11}{'PZT cover':>11}"
         f"{'flagged':>9}")
    for b in bands.band.values:
        row = bands.sel(band=b).isel(output=0)
        e, c = row.median_error, row.coverage
        echo(f"  {str(b):<16}{float(e.sel(input='vcm')):>11.2e}{float(e.sel(input='pzt')):>11.2e}"
             f"{float(c.sel(input='vcm')):>11.2f}{float(c.sel(input='pzt')):>11.2f}"
             f"{float(row.flagged.max()):>9.2f}")
    echo("main PZT resonance peaks (true vs estimated frequency):")
    for true_hz, est_hz in peaks:
        echo(f"  {true_hz:10.0f} Hz   {est_hz:10.0f} Hz   ({est_hz - true_hz:+.0f} Hz)")
    for f in files:
        echo(f"wrote {f}")
    return {"frf": frf, "errors": errors, "bands": bands, "peaks": peaks, "files": files,
            "seconds": seconds}


def _plots(frf, truth, out_dir):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from lcmr_xr.plot import bode, save_figure

    full = bode(frf, truth=truth, band=0.95, nyquist=True)
    full.figure.suptitle("Dual-stage HDD: lifted closed-loop LRM estimate vs exact FRF\n"
                         "(95 % band; hatched: not determined by the data, unbounded band)")
    p1 = out_dir / OUTPUT_NAMES[1]
    save_figure(full, p1)
    zoom = bode(frf.sel(input=["pzt"]), truth=truth.sel(input=["pzt"]), band=0.95,
                nyquist=True, xlim=PZT_ZOOM_HZ)
    zoom.figure.suptitle("PZT resonances beyond the slow Nyquist frequency")
    p2 = out_dir / OUTPUT_NAMES[2]
    save_figure(zoom, p2)
    plt.close("all")
    return [p1, p2]
