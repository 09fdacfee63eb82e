"""Command line: ``lcmr-xr identify | demo | simulate | sweep | archive``.

    lcmr-xr identify EXPERIMENT.nc|.mat -o FRF.nc|.mat [--method lrm|lpm] [--window N|auto]
                     [--degrees RN-RM-RD] [--closed-loop indirect|direct] [--denominator ls|iv]
                     [--plot FILE.png]
                     [--overwrite]
    lcmr-xr demo [--experiment FILE.nc] [--output-dir DIR] [--window N|auto] [--degrees RN-RM-RD]
                 [--overwrite]
    lcmr-xr simulate -o EXPERIMENT.nc [--samples N] [--case 1..9] [--seed S] [--noiseless]
                     [--disturbances rotational fan runout] [--overwrite]
    lcmr-xr sweep ARCHIVE -o RESULT.nc --window 10 20 30 [--degrees 3-3-3 ...]
                  [--method lrm lpm] [--scheduler threads|processes|ADDRESS] [--overwrite]
    lcmr-xr archive consolidate ARCHIVE_DIR -o ARCHIVE.nc [--overwrite]
    lcmr-xr archive index ARCHIVE_DIR

Errors in the input (a missing or foreign file, bad settings) print one line that says
what is wrong and exit with status 2; nothing is written then.  Every output path is
checked before any computation: no command writes over one of its own inputs, and an
existing output file is replaced only with ``--overwrite``.  Long work shows progress on
stderr (plain lines when stderr is not a terminal).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from lcmr_xr._cli_support import (DENOMINATOR_HELP, FIGURE_SUFFIXES, MAT_SUFFIX, NETCDF_SUFFIXES,
                                  HelpFormatter, add_overwrite, check_outputs, error_line,
                                  heartbeat, integer_argument)
from lcmr_xr.settings import CLOSED_LOOP, DEFAULT_WINDOW, DENOMINATOR, METHODS, window_argument

#: Help text of every ``--degrees`` option: one syntax on every command line.
DEGREES_HELP = ("local model degrees RN-RM-RD: numerator, transient, denominator (default "
                "3-3-3; LPM: 3-3-0, its RD must be 0)")


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="lcmr-xr",
        description="Lifted closed-loop multirate FRF identification (lcmr_xr).",
    )
    sub = p.add_subparsers(dest="command", required=True)

    ident = sub.add_parser("identify", help="identify the fast FRF of an experiment file",
                           formatter_class=HelpFormatter)
    ident.add_argument("experiment", type=Path,
                       help="experiment file: NetCDF (lcmr-xr-1), or MATLAB .mat with the "
                            "variables r, u, y, F and Ts (as lcmr_xr.open_experiment reads it)")
    ident.add_argument("-o", "--output", type=Path, required=True,
                       help="FRF file to write: .nc (NetCDF), or .mat for MATLAB's frd (P, "
                            "frequency, Ts, InputName, OutputName)")
    ident.add_argument("--method", choices=tuple(METHODS), default="lrm",
                       help="local rational (lrm) or polynomial (lpm) model")
    ident.add_argument("--window", type=window_argument, default=DEFAULT_WINDOW,
                       help="local window half-width n (2n+1 bins), or 'auto': chosen per bin")
    ident.add_argument("--degrees", nargs="+", metavar="RN-RM-RD", default=None, help=DEGREES_HELP)
    ident.add_argument("--closed-loop", choices=tuple(CLOSED_LOOP), default="indirect",
                       help="indirect: P = PS S^-1 from the excitation (unbiased); direct: from "
                            "the measured input (biased under feedback)")
    ident.add_argument("--denominator", choices=tuple(DENOMINATOR), default=None,
                       help=DENOMINATOR_HELP)
    ident.add_argument("--plot", type=Path, default=None,
                       help="also write a Bode plot PNG (default: no plot)")
    add_overwrite(ident)

    demo = sub.add_parser("demo", help="identify the bundled HDD benchmark experiment",
                          formatter_class=HelpFormatter)
    demo.add_argument("--experiment", type=Path, default=None,
                      help="experiment file, .nc or .mat as for identify (default: the bundled "
                           "datasets/hdd_case2_N3600.nc, simulated when missing)")
    demo.add_argument("--output-dir", type=Path, default=Path("demo-output"),
                      help="directory for hdd_frf.nc and the Bode plots (created if missing)")
    demo.add_argument("--window", type=window_argument, default=DEFAULT_WINDOW,
                      help="local window half-width n (2n+1 bins), or 'auto': chosen per bin")
    demo.add_argument("--degrees", nargs="+", metavar="RN-RM-RD", default=["3-3-3"], help=DEGREES_HELP)
    demo.add_argument("--no-plot", action="store_true",
                      help="skip the PNG Bode plots (default: write them)")
    add_overwrite(demo)

    sim = sub.add_parser("simulate", help="simulate the HDD benchmark experiment to a file",
                         formatter_class=HelpFormatter)
    sim.add_argument("-o", "--output", type=Path, required=True,
                     help="experiment NetCDF file to write (.nc)")
    sim.add_argument("--samples", type=integer_argument, default=3600, help="number N of fast samples")
    sim.add_argument("--case", type=integer_argument, default=2, choices=range(1, 10), metavar="1..9",
                     help="HDD benchmark case (plant variant)")
    sim.add_argument("--seed", type=integer_argument, default=0, help="seed of the excitation and noise")
    sim.add_argument("--noiseless", action="store_true",
                     help="no disturbances or measurement noise (default: with noise)")
    sim.add_argument("--disturbances", nargs="+", choices=DISTURBANCES, default=list(DISTURBANCES),
                     metavar="NAME", help="the benchmark disturbances that act, any of "
                     f"{', '.join(DISTURBANCES)} (default: all); the same realisations as with "
                     "all of them, to see what each costs the estimate")
    add_overwrite(sim)

    from lcmr_xr.scaleout.archive_cli import add_archive_parser
    from lcmr_xr.scaleout.cli import add_sweep_parser

    add_sweep_parser(sub)
    add_archive_parser(sub)
    return p


def _one_degrees(args):
    """The single ``--degrees`` setting of identify/demo (None: the method's default)."""
    from lcmr_xr.settings import degrees_arguments

    if args.degrees is None:
        return None
    settings = degrees_arguments(args.degrees)
    if len(settings) != 1:
        raise ValueError(f"--degrees takes one setting RN-RM-RD here, got {len(settings)} "
                         f"({' '.join(settings)}); use 'lcmr-xr sweep' to compare several.")
    return settings[0]


def _identify(args) -> int:
    from lcmr_xr import conventions as cv
    from lcmr_xr.identification import identify
    from lcmr_xr.io import open_experiment, save
    from lcmr_xr.settings import estimator_settings

    # the settings first: a typo is reported before the experiment is read
    s = estimator_settings(method=args.method, window=args.window, degrees=_one_degrees(args),
                           closed_loop=args.closed_loop, denominator=args.denominator)
    check_outputs({"-o": (args.output, NETCDF_SUFFIXES + (MAT_SUFFIX,)),
                   "--plot": (args.plot, FIGURE_SUFFIXES)},
                  inputs=[args.experiment], overwrite=args.overwrite)
    exp = open_experiment(args.experiment)
    # the dims that stay in the result (the periods of a record are pooled into its FRF)
    leading = [d for d in exp["r"].dims if d not in (cv.TIME, cv.INPUT, cv.PERIOD)]
    if leading and args.output.suffix.lower() == MAT_SUFFIX:  # before the work, not after it
        raise ValueError(f"-o {args.output}: a .mat file holds one FRF, but {args.experiment} holds "
                         f"experiments along {leading}; write a .nc file, or select one experiment "
                         f"first (lcmr_xr.save(ds.isel({leading[0]}=0), ...)).")
    with heartbeat(f"identifying {args.experiment.name} ({exp.sizes['slow_time']} slow bins, "
                   f"{s.method}, window {s.window})", sys.stderr):
        frf = identify(exp, method=s.method, window=s.window, degrees=s.degrees,
                       closed_loop=s.closed_loop, denominator=args.denominator)
    save(frf, args.output)
    print(f"wrote {args.output}: P {dict(frf.P.sizes)}, "
          f"{int(frf.P_flag.sum())} flagged bins, method {args.method}, window {args.window}")
    if args.plot is not None:
        import matplotlib

        matplotlib.use("Agg")
        from lcmr_xr.plot import bode, save_figure

        save_figure(bode(frf, title=f"{Path(args.experiment).name}: {frf.attrs['title']} (window {frf.attrs['window']}, degrees {', '.join(str(int(d)) for d in frf.attrs['degrees'])})"), args.plot)
        print(f"wrote {args.plot}")
    return 0


#: ``lcmr_xr.hdd.DISTURBANCES``, spelled out: importing the HDD package would double the
#: start-up of every command (the tests check that the two agree).
DISTURBANCES = ("rotational", "fan", "runout")


def _simulate(args) -> int:
    from lcmr_xr import hdd
    from lcmr_xr.io import save

    check_outputs({"-o": (args.output, NETCDF_SUFFIXES)}, overwrite=args.overwrite)
    if args.noiseless and sorted(args.disturbances) != sorted(hdd.DISTURBANCES):
        raise ValueError("--noiseless switches every disturbance off; leave out --disturbances, "
                         "or drop --noiseless to simulate the chosen ones.")
    # the options' own names in the messages (hdd.simulate's would say n_samples, seed=0)
    hdd.benchmark.check_n_samples(args.samples, "--samples")
    hdd.benchmark.check_seed(args.seed, "--seed")
    exp = hdd.simulate(n_samples=args.samples, case=args.case, noise=not args.noiseless,
                       seed=args.seed, disturbances=args.disturbances)
    save(exp, args.output)
    what = "no disturbances" if args.noiseless else "disturbances: " + exp.attrs["disturbances"]
    print(f"wrote {args.output}: N = {exp.sizes['time']}, case {args.case}, seed {args.seed}, {what}")
    return 0


def main(argv=None) -> int:
    """Entry point of the ``lcmr-xr`` console script; returns the exit status."""
    args = _parser().parse_args(argv)
    try:
        if args.command == "identify":
            return _identify(args)
        if args.command == "demo":
            from lcmr_xr.demo import output_files, run_demo

            from lcmr_xr.settings import estimator_settings

            s = estimator_settings(window=args.window, degrees=_one_degrees(args))
            if args.output_dir.exists() and not args.output_dir.is_dir():
                raise NotADirectoryError(f"--output-dir {args.output_dir} is a file; give a directory.")
            if args.output_dir.is_dir():  # a new directory has no files to protect
                check_outputs({f"--output-dir file {p.name}": (p, None)
                               for p in output_files(args.output_dir, plot=not args.no_plot)},
                              inputs=[args.experiment], overwrite=args.overwrite)
            run_demo(args.experiment, args.output_dir, window=s.window,
                     degrees=s.degrees, plot=not args.no_plot)
            return 0
        if args.command == "simulate":
            return _simulate(args)
        if args.command in ("sweep", "archive"):
            return args.func(args)
    except (ValueError, TypeError, FileNotFoundError, OSError) as exc:
        print(error_line(args.command, exc), file=sys.stderr)
        return 2
    return 2  # unreachable: argparse requires a command


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
