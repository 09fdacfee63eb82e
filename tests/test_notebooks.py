"""The notebooks and the README run as written.

* the notebooks are jupytext percent scripts, ``notebooks/*.py`` (one source, reviewable
  and mergeable as Python; no ``.ipynb`` is committed): each is read with jupytext and
  executed top to bottom with nbclient, in a kernel started from the running
  interpreter (a kernel spec written to a temporary prefix, so a fresh ``.venv`` in CI
  needs no ``jupyter kernelspec install``), with ``MPLBACKEND=Agg`` and a temporary
  working directory;
* each script is in jupytext's canonical percent form (writing it back changes nothing),
  and an ``.ipynb`` made from it and kept next to it (``jupytext --set-formats
  ipynb,py:percent``) must hold the same cells: a pair out of sync fails;
* every ```python block of README.md runs, in order, in one fresh interpreter in a
  temporary directory, and the pictures the README shows exist.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
NOTEBOOKS = ROOT / "notebooks"
README = ROOT / "README.md"
CELL_TIMEOUT_S = 120
# The heavier notebooks (seed averages, a sweep) take 15-25 s each on 2 cores.
SLOW_NOTEBOOKS = {"02_methods_compared.py", "03_archive_and_sweeps.py"}
# Percent cells and nothing else: no YAML header, no cell metadata.
PERCENT = {"extension": ".py", "format_name": "percent",
           "notebook_metadata_filter": "-all", "cell_metadata_filter": "-all"}
README_HEAD = (
    "# lcmr_xr\n"
    "\n"
    "```\n"
    "make demo   # creates .venv, installs, identifies the bundled HDD benchmark experiment\n"
    "make test   # creates .venv if needed, installs with test extras, runs the whole suite\n"
    "```\n"
)


def _notebook_paths():
    return sorted(NOTEBOOKS.glob("*.py"))


def _notebook_params():
    return [pytest.param(p, id=p.stem,
                         marks=[pytest.mark.slow] if p.name in SLOW_NOTEBOOKS else [])
            for p in _notebook_paths()]


def _read(path):
    import jupytext

    return jupytext.read(path, fmt="py:percent")


@pytest.fixture(scope="module")
def kernel_name(tmp_path_factory):
    """A kernel spec whose argv is ``sys.executable -m ipykernel_launcher``, in a temp prefix."""
    from ipykernel.kernelspec import install

    prefix = tmp_path_factory.mktemp("kernel-prefix")
    name = "lcmr-xr-test-python"
    install(user=False, prefix=str(prefix), kernel_name=name)
    return name, prefix / "share" / "jupyter" / "kernels"


def test_every_notebook_is_collected():
    # an empty glob would make the parametrised execution test pass vacuously
    names = [p.name for p in _notebook_paths()]
    assert names == ["01_hdd_benchmark.py", "02_methods_compared.py", "03_archive_and_sweeps.py"]


def _execute(nb, kernel, workdir):
    """Run ``nb`` in place with the test kernel, working directory ``workdir``, no display."""
    from jupyter_client.kernelspec import KernelSpecManager
    from jupyter_client.manager import KernelManager
    from nbclient import NotebookClient

    name, kernel_dir = kernel
    km = KernelManager(kernel_name=name,
                       kernel_spec_manager=KernelSpecManager(kernel_dirs=[str(kernel_dir)]))
    client = NotebookClient(nb, km=km, timeout=CELL_TIMEOUT_S,
                            resources={"metadata": {"path": str(workdir)}})
    return client.execute()  # raises CellExecutionError (cell source + traceback) on an error


@pytest.mark.notebook
@pytest.mark.parametrize("path", _notebook_params())
def test_notebook_executes(path, kernel_name, tmp_path, monkeypatch):
    monkeypatch.setenv("MPLBACKEND", "Agg")  # the kernel inherits the environment
    nb = _read(path)
    _execute(nb, kernel_name, tmp_path)

    code_cells = [c for c in nb.cells if c.cell_type == "code"]
    assert code_cells and all(c.execution_count is not None for c in code_cells)
    assert [o for c in code_cells for o in c.outputs if o.output_type == "error"] == []


@pytest.mark.notebook
def test_runner_uses_this_interpreter_a_temp_dir_and_no_display(kernel_name, tmp_path, monkeypatch):
    import nbformat
    from nbformat.v4 import new_code_cell, new_notebook

    monkeypatch.setenv("MPLBACKEND", "Agg")
    probe = new_notebook(cells=[new_code_cell(
        "import os, sys, matplotlib\n"
        "print(sys.executable, os.getcwd(), matplotlib.get_backend(), sep='\\n')")])
    _execute(probe, kernel_name, tmp_path)
    lines = probe.cells[0].outputs[0].text.split()
    assert lines[0] == sys.executable
    assert Path(lines[1]).resolve() == tmp_path.resolve()
    assert lines[2].lower() == "agg"
    nbformat.validate(probe)


@pytest.mark.notebook
def test_runner_fails_on_an_error_cell(kernel_name, tmp_path):
    from nbclient.exceptions import CellExecutionError
    from nbformat.v4 import new_code_cell, new_notebook

    broken = new_notebook(cells=[new_code_cell("x = 1"), new_code_cell("raise ValueError('boom 42')")])
    with pytest.raises(CellExecutionError, match="boom 42"):
        _execute(broken, kernel_name, tmp_path)


@pytest.mark.parametrize("path", _notebook_paths(), ids=lambda p: p.stem)
def test_notebook_scripts_are_canonical_percent_scripts(path):
    import jupytext
    import nbformat

    text = path.read_text()
    nb = _read(path)
    nbformat.validate(nb)
    kinds = [c.cell_type for c in nb.cells]
    assert kinds[0] == "markdown" and "code" in kinds, f"{path.name}: not a percent notebook"
    assert all(c.source.strip() for c in nb.cells), f"{path.name} has an empty cell"
    # what jupytext (or Jupyter with jupytext) writes back is the committed text
    assert jupytext.writes(nb, fmt=PERCENT) == text, \
        f"{path.name} is not in canonical percent form; run jupytext --to py:percent on it"


def _cells(nb):
    return [(c.cell_type, c.source) for c in nb.cells]


def test_no_notebook_json_is_committed():
    tracked = subprocess.run(["git", "ls-files", "notebooks"], cwd=ROOT, capture_output=True,
                             text=True)
    if tracked.returncode != 0:
        pytest.skip("not a git checkout")
    assert [n for n in tracked.stdout.split() if n.endswith(".ipynb")] == [], \
        "commit the percent scripts only: the .ipynb is made from them"


def _out_of_sync(script: Path) -> str | None:
    """Why the ``.ipynb`` next to ``script`` differs from it, or None (also when there is none)."""
    import nbformat

    paired = script.with_suffix(".ipynb")
    if paired.exists() and _cells(nbformat.read(paired, as_version=4)) != _cells(_read(script)):
        return f"{paired.name} and {script.name} differ: run jupytext --sync {script.name}"
    return None


def test_paired_notebooks_are_in_sync():
    """An .ipynb kept next to a script (jupytext pairing, Jupyter) holds the same cells."""
    problems = [p for p in map(_out_of_sync, _notebook_paths()) if p]
    assert problems == []


def test_out_of_sync_pair_is_detected(tmp_path):
    import jupytext

    script = tmp_path / "01_hdd_benchmark.py"
    script.write_text((NOTEBOOKS / script.name).read_text())
    jupytext.write(_read(script), script.with_suffix(".ipynb"), fmt="ipynb")
    assert _out_of_sync(script) is None  # a freshly paired notebook is in sync
    script.write_text(script.read_text().replace("N, SEED = 3600", "N, SEED = 3601"))
    assert "differ: run jupytext --sync" in _out_of_sync(script)


# ---------------------------------------------------------------------------- README


def readme_python_blocks(text: str) -> list[tuple[int, str]]:
    """``(line number, code)`` of every fenced block opened by exactly ```python."""
    blocks = []
    for match in re.finditer(r"^```python[ \t]*\n(.*?)^```[ \t]*$", text, flags=re.M | re.S):
        blocks.append((text.count("\n", 0, match.start()) + 1, match.group(1)))
    return blocks


def test_block_extraction():
    text = textwrap.dedent("""\
        intro
        ```python
        a = 1
        ```
        ```bash
        not python
        ```
        ```python
        b = a + 1
        ```
        """)
    assert readme_python_blocks(text) == [(2, "a = 1\n"), (8, "b = a + 1\n")]


def test_readme_starts_with_the_two_commands():
    assert README.read_text().startswith(README_HEAD)


def test_readme_python_blocks_run(tmp_path):
    blocks = readme_python_blocks(README.read_text())
    assert len(blocks) >= 4  # example, own data, validation, accessor
    script = "\n".join(f"# --- README.md line {line} ---\n{code}" for line, code in blocks)
    (tmp_path / "readme_blocks.py").write_text(script)
    env = {**os.environ, "MPLBACKEND": "Agg"}
    done = subprocess.run([sys.executable, "readme_blocks.py"], cwd=tmp_path, env=env,
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, f"README code failed:\n{done.stderr[-4000:]}"
    # the example writes its Bode plot where it runs
    assert (tmp_path / "hdd_bode.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_readme_pictures_exist():
    pictures = re.findall(r"!\[[^\]]*\]\(([^)]+)\)", README.read_text())
    assert pictures, "README shows no picture"
    for rel in pictures:
        path = ROOT / rel
        assert path.is_file(), f"README shows {rel}; run docs/make_figures.py"
        assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
