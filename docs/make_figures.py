"""Draw the pictures of README.md into docs/img/ (committed; rerun after a change).

    .venv/bin/python docs/make_figures.py [--output-dir DIR]

The calls are those of the README's first example, so the picture shows what that
code produces: the paper's HDD experiment (N = 3600, F = 2, benchmark disturbances,
seed 0) identified with LRM, degrees (3, 3, 3) and the default window="auto" (chosen per
bin); hatched spans mark bins the data do not determine (unbounded band).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # a script that only writes files: no display needed

import matplotlib.pyplot as plt  # noqa: E402

import lcmr_xr  # noqa: E402
from lcmr_xr import hdd, plot  # noqa: E402

IMG = Path(__file__).resolve().parent / "img"
PZT_BAND_HZ = (38e3, 50.4e3)


def make_figures(output_dir=IMG) -> list[Path]:
    """Simulate and identify the paper's HDD experiment and draw the README pictures.

    Parameters
    ----------
    output_dir : str or pathlib.Path, default ``docs/img`` next to this script
        Directory for ``hdd_bode.png`` (VCM and PZT, DC to 50.4 kHz, 95 % band, exact
        FRF dashed) and ``hdd_pzt_zoom.png`` (PZT, 38-50.4 kHz); created if missing.

    Returns
    -------
    list of pathlib.Path
        The two PNG files written (100 dpi).

    Examples
    --------
    >>> import tempfile
    >>> with tempfile.TemporaryDirectory() as tmp:  # doctest: +SKIP
    ...     [p.name for p in make_figures(tmp)]
    ['hdd_bode.png', 'hdd_pzt_zoom.png']
    """
    output_dir = Path(output_dir)
    output_dir.mkdir(parents=True, exist_ok=True)
    exp = hdd.simulate(n_samples=3600, noise=True, seed=0)
    frf = lcmr_xr.identify(exp, method="lrm", degrees=(3, 3, 3))
    # the VCM's rigid-body mode makes the exact FRF infinite at DC: leave DC out
    truth = hdd.true_frf(frf.frequency[1:]).reindex(frequency=frf.frequency)

    full = plot.bode(frf, truth=truth, band=0.95)
    full.figure.set_size_inches(10, 5.5)
    full.figure.suptitle("Dual-stage HDD benchmark: lifted closed-loop LRM estimate (N = 3600, F = 2)")
    zoom = plot.bode(frf.sel(input=["pzt"]), truth=truth.sel(input=["pzt"]), band=0.95,
                     xlim=PZT_BAND_HZ)
    zoom.figure.set_size_inches(6, 5)
    zoom.figure.suptitle("PZT resonances beyond the slow Nyquist frequency (25.2 kHz)")
    paths = [plot.save_figure(full, output_dir / "hdd_bode.png", dpi=100),
             plot.save_figure(zoom, output_dir / "hdd_pzt_zoom.png", dpi=100)]
    plt.close("all")
    return paths


def main(argv=None) -> int:
    """Command line entry: write the figures and print their paths.

    Parameters
    ----------
    argv : list of str, optional
        Arguments (``--output-dir DIR``); default None reads ``sys.argv``.

    Returns
    -------
    int
        Exit status 0.

    Examples
    --------
    >>> main(["--output-dir", "/tmp/lcmr-figures"])  # doctest: +SKIP
    0
    """
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--output-dir", type=Path, default=IMG, help=f"default {IMG}")
    args = parser.parse_args(argv)
    for path in make_figures(args.output_dir):
        print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
