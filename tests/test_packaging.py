"""The package builds without setuptools deprecation warnings (SPDX licence string, PEP 639)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def test_metadata_builds_without_deprecation_warnings(tmp_path):
    """What `pip install` runs first: setuptools' metadata hook, with every warning shown."""
    code = ("import sys; from setuptools import build_meta; "
            "print(build_meta.prepare_metadata_for_build_wheel(sys.argv[1]))")
    done = subprocess.run([sys.executable, "-W", "always", "-c", code, str(tmp_path)], cwd=ROOT,
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-3000:]
    output = done.stdout + done.stderr
    assert "deprecat" not in output.lower(), output[-3000:]
    metadata = (tmp_path / done.stdout.split()[-1] / "METADATA").read_text()
    assert "License-Expression: BSD-3-Clause" in metadata
    extras = [line for line in metadata.splitlines() if line.startswith("Provides-Extra:")]
    assert sorted(extras) == ["Provides-Extra: control", "Provides-Extra: test"]
