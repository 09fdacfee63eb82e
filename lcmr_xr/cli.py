"""Command line: ``lcmr-xr identify | demo | simulate | sweep``.

    lcmr-xr identify EXPERIMENT.nc -o FRF.nc [--method lrm|lpm] [--window N]
                     [--degrees RN RM RD] [--closed-loop indirect|direct] [--plot FILE.png]
    lcmr-xr demo [--experiment FILE.nc] [--output-dir DIR]
    lcmr-xr simulate -o EXPERIMENT.nc [--samples N] [--case 1..9] [--seed S] [--noiseless]
    lcmr-xr sweep ARCHIVE_DIR -o RESULT.nc --window 10 20 30 [--degrees 3-3-3 ...]
                  [--method lrm lpm] [--scheduler threads|processes|ADDRESS]
    lcmr-xr archive consolidate ARCHIVE_DIR -o ARCHIVE.nc [--overwrite]

Errors in the input (a missing or foreign file, bad settings) print one line that says
what is wrong and exit with status 2; nothing is written then.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="lcmr-xr",
        description="Lifted closed-loop multirate FRF identification (lcmr_xr).",
    )
    sub = p.add_subparsers(dest="command", required=True)

    ident = sub.add_parser("identify", help="identify the fast FRF of an experiment file")
    ident.add_argument("experiment", type=Path, help="experiment NetCDF file (lcmr-xr-1)")
    ident.add_argument("-o", "--output", type=Path, required=True, help="FRF NetCDF file to write")
    ident.add_argument("--method", choices=("lrm", "lpm"), default="lrm")
    ident.add_argument("--window", type=int, default=30, help="local window half-width n (2n+1 bins)")
    ident.add_argument("--degrees", type=int, nargs=3, metavar=("RN", "RM", "RD"), default=None,
                       help="numerator, transient and denominator degrees (default 3 3 3; LPM: 3 3 0)")
    ident.add_argument("--closed-loop", choices=("indirect", "direct"), default="indirect")
    ident.add_argument("--plot", type=Path, default=None, help="also write a Bode plot PNG")

    demo = sub.add_parser("demo", help="identify the bundled HDD benchmark experiment")
    demo.add_argument("--experiment", type=Path, default=None)
    demo.add_argument("--output-dir", type=Path, default=Path("demo-output"))
    demo.add_argument("--window", type=int, default=30)
    demo.add_argument("--degrees", type=int, nargs=3, default=(3, 3, 3), metavar=("RN", "RM", "RD"))
    demo.add_argument("--no-plot", action="store_true")

    sim = sub.add_parser("simulate", help="simulate the HDD benchmark experiment to a file")
    sim.add_argument("-o", "--output", type=Path, required=True)
    sim.add_argument("--samples", type=int, default=3600)
    sim.add_argument("--case", type=int, default=2, choices=range(1, 10))
    sim.add_argument("--seed", type=int, default=0)
    sim.add_argument("--noiseless", action="store_true")

    from lcmr_xr.scaleout.archive_cli import add_archive_parser
    from lcmr_xr.scaleout.cli import add_sweep_parser

    add_sweep_parser(sub)
    add_archive_parser(sub)
    return p


def _identify(args) -> int:
    from lcmr_xr.identification import identify
    from lcmr_xr.io import open_experiment, save

    exp = open_experiment(args.experiment)
    frf = identify(exp, method=args.method, window=args.window, degrees=args.degrees,
                   closed_loop=args.closed_loop)
    save(frf, args.output)
    print(f"wrote {args.output}: P {dict(frf.P.sizes)}, "
          f"{int(frf.P_flag.sum())} flagged bins, method {args.method}, window {args.window}")
    if args.plot is not None:
        import matplotlib

        matplotlib.use("Agg")
        from lcmr_xr.plot import bode, save_figure

        save_figure(bode(frf), args.plot)
        print(f"wrote {args.plot}")
    return 0


def _simulate(args) -> int:
    from lcmr_xr import hdd
    from lcmr_xr.io import save

    exp = hdd.simulate(n_samples=args.samples, case=args.case, noise=not args.noiseless,
                       seed=args.seed)
    save(exp, args.output)
    print(f"wrote {args.output}: N = {exp.sizes['time']}, case {args.case}, seed {args.seed}")
    return 0


def main(argv=None) -> int:
    """Entry point of the ``lcmr-xr`` console script; returns the exit status."""
    args = _parser().parse_args(argv)
    try:
        if args.command == "identify":
            return _identify(args)
        if args.command == "demo":
            from lcmr_xr.demo import run_demo

            run_demo(args.experiment, args.output_dir, window=args.window,
                     degrees=tuple(args.degrees), plot=not args.no_plot)
            return 0
        if args.command == "simulate":
            return _simulate(args)
        if args.command in ("sweep", "archive"):
            return args.func(args)
    except (ValueError, TypeError, FileNotFoundError, OSError) as exc:
        print(f"lcmr-xr {args.command}: error: {exc}", file=sys.stderr)
        return 2
    return 2  # unreachable: argparse requires a command


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
