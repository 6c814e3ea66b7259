"""The tutorial notebook (docs/tutorial.ipynb) runs from top to bottom and makes its figure."""

from __future__ import annotations

from pathlib import Path

import pytest

import ngbet

NOTEBOOK = Path(__file__).resolve().parent.parent / "docs" / "tutorial.ipynb"


@pytest.mark.integration
def test_the_tutorial_runs_and_writes_its_figure(tmp_path):
    nbformat = pytest.importorskip("nbformat")
    nbclient = pytest.importorskip("nbclient")
    if not NOTEBOOK.exists():
        pytest.skip("the docs are not beside the tests (tests run against an installed package)")
    nb = nbformat.read(NOTEBOOK, as_version=4)
    # raises CellExecutionError, with the cell and its traceback, when a cell fails
    nbclient.NotebookClient(
        nb, timeout=600, kernel_name="python3", resources={"metadata": {"path": str(tmp_path)}}
    ).execute()
    assert (tmp_path / "bet_two_fabrics.pdf").stat().st_size > 10_000
    assert (tmp_path / "bet_two_fabrics.png").stat().st_size > 50_000
    runs = [ngbet.load_result(tmp_path / "runs" / str(i)) for i in (0, 1)]
    assert [r.status for r in runs] == ["ok", "ok"]
    assert all(r.u0_mm[-1] == 40.0 for r in runs)
    # the unbalanced fabric's thick yarns (alpha1 = 100 alpha2) resist the S-shape: a larger force
    assert runs[0].force_N[-1] > 2 * runs[1].force_N[-1]
    printed = "".join(o.get("text", "") for c in nb.cells if c.cell_type == "code" for o in c.get("outputs", []))
    assert f"F(40 mm) = {runs[0].force_N[-1]:.2f} N" in printed
