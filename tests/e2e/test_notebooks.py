"""Every notebook in colab/ runs from top to bottom without an error.

Each notebook is executed in a fresh kernel of the interpreter that runs the
tests, with JAXROUND_LOCAL=1 (use the installed checkout, install nothing) and
JAXROUND_QUICK=1 (the small budget), in a temporary folder; the notebook files
in the repository are not modified. About a minute per notebook in a full
run on a 2-core CPU, most of it compiling the environment's step.
"""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import pytest

nbformat = pytest.importorskip("nbformat")
nbclient = pytest.importorskip("nbclient")
kernelspec = pytest.importorskip("ipykernel.kernelspec")

ROOT = Path(__file__).resolve().parents[2]
NOTEBOOKS = sorted((ROOT / "colab").glob("*.ipynb"))
#: Seconds one cell may run.
CELL_TIMEOUT_S = 600
#: Set in the kernel's environment (which inherits the session's few
#: optimisations, `conftest.pytest_configure`).
KERNEL_ENV = {
    "JAXROUND_LOCAL": "1",
    "JAXROUND_QUICK": "1",
}


def kernel_env() -> dict[str, str]:
    """The tests' environment for the kernel, with the notebooks' switches.

    MPLBACKEND is dropped so that the kernel draws with its inline backend.
    """
    env = {k: v for k, v in os.environ.items() if k != "MPLBACKEND"}
    env.update(KERNEL_ENV)
    return env


def test_there_are_notebooks() -> None:
    assert NOTEBOOKS, "no notebook in colab/"


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.name)
def test_notebook_runs(
    path: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # a kernelspec "python3" that starts this interpreter, found first
    spec = kernelspec.write_kernel_spec(tmp_path / "jupyter" / "kernels" / "python3")
    argv = json.loads((Path(spec) / "kernel.json").read_text())["argv"]
    assert argv[0] == sys.executable
    monkeypatch.setenv("JUPYTER_PATH", str(tmp_path / "jupyter"))
    work = tmp_path / "work"
    work.mkdir()
    nb = nbformat.read(path, as_version=4)
    client = nbclient.NotebookClient(
        nb,
        kernel_name="python3",
        timeout=CELL_TIMEOUT_S,
        resources={"metadata": {"path": str(work)}},
    )
    client.execute(env=kernel_env())  # raises CellExecutionError on a failing cell
    errors = [
        out
        for cell in nb.cells
        if cell.cell_type == "code"
        for out in cell.get("outputs", [])
        if out.get("output_type") == "error"
    ]
    assert not errors, errors
