"""The notebooks and the README run as written.

* every ``notebooks/*.ipynb`` executes top to bottom with nbclient, in a kernel started
  from the running interpreter (a kernel spec written to a temporary prefix, so a
  fresh ``.venv`` in CI needs no ``jupyter kernelspec install``), with ``MPLBACKEND=Agg``
  and a temporary working directory;
* the committed notebooks carry no outputs and are exactly what ``notebooks/_build.py``
  writes (so they stay reviewable as Python);
* every ```python block of README.md runs, in order, in one fresh interpreter in a
  temporary directory, and the pictures the README shows exist.
"""

from __future__ import annotations

import importlib.util
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
SLOW_NOTEBOOKS = {"02_methods_compared.ipynb", "03_archive_and_sweeps.ipynb"}
README_HEAD = (
    "# lcmr_xr\n"
    "\n"
    "```\n"
    "make demo   # creates .venv, installs, identifies the bundled HDD benchmark experiment\n"
    "make test   # creates .venv if needed, installs with test extras, runs the whole suite\n"
    "```\n"
)


def _notebook_paths():
    return sorted(NOTEBOOKS.glob("*.ipynb"))


def _notebook_params():
    return [pytest.param(p, id=p.stem,
                         marks=[pytest.mark.slow] if p.name in SLOW_NOTEBOOKS else [])
            for p in _notebook_paths()]


@pytest.fixture(scope="module")
def kernel_name(tmp_path_factory):
    """A kernel spec whose argv is ``sys.executable -m ipykernel_launcher``, in a temp prefix."""
    from ipykernel.kernelspec import install

    prefix = tmp_path_factory.mktemp("kernel-prefix")
    name = "lcmr-xr-test-python"
    install(user=False, prefix=str(prefix), kernel_name=name)
    return name, prefix / "share" / "jupyter" / "kernels"


def _load_builder():
    spec = importlib.util.spec_from_file_location("lcmr_notebook_builder", NOTEBOOKS / "_build.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_every_notebook_is_collected():
    # an empty glob would make the parametrised execution test pass vacuously
    names = [p.name for p in _notebook_paths()]
    assert names == ["01_hdd_benchmark.ipynb", "02_methods_compared.ipynb",
                     "03_archive_and_sweeps.ipynb"]


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
    import nbformat

    monkeypatch.setenv("MPLBACKEND", "Agg")  # the kernel inherits the environment
    nb = nbformat.read(path, as_version=4)
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
def test_committed_notebook_has_no_outputs(path):
    import nbformat

    nb = nbformat.read(path, as_version=4)
    nbformat.validate(nb)
    dirty = [i for i, c in enumerate(nb.cells) if c.cell_type == "code"
             and (c.outputs or c.execution_count is not None)]
    assert dirty == [], f"{path.name}: cells {dirty} have outputs; run notebooks/_build.py"


def test_committed_notebooks_are_what_the_builder_writes():
    import nbformat

    built = _load_builder().build_notebooks()
    assert sorted(built) == [p.name for p in _notebook_paths()]
    for name, nb in built.items():
        committed = nbformat.read(NOTEBOOKS / name, as_version=4)
        assert [(c.cell_type, c.source) for c in committed.cells] == \
               [(c.cell_type, c.source) for c in nb.cells], \
               f"{name} differs from notebooks/_build.py; rerun it"


def test_builder_refuses_unknown_names(capsys):
    assert _load_builder().main(["04_missing.ipynb"]) == 2
    assert "unknown notebook" in capsys.readouterr().err


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
