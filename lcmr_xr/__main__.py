"""``python -m lcmr_xr``: the ``lcmr-xr`` command line (:func:`lcmr_xr.cli.main`).

For environments where the console script is not on ``PATH`` (a venv that is not
activated, ``PYTHONPATH`` checkouts): ``python -m lcmr_xr identify e.nc -o frf.nc``.
"""

import sys

from lcmr_xr.cli import main

if __name__ == "__main__":  # imported by pkgutil walks (doctests): run only as a script
    sys.exit(main())
