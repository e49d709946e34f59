"""docs/examples/analysis.ipynb runs from a fresh run's logs, within 60 s, and is kept without outputs."""

from __future__ import annotations

import time
from pathlib import Path

import pytest

from tests.test_replay import PROTOCOLS

NOTEBOOK = Path(__file__).resolve().parent.parent / "docs" / "examples" / "analysis.ipynb"
MAX_SECONDS = 60.0


def test_the_notebook_is_committed_without_outputs():
    nbformat = pytest.importorskip("nbformat")
    notebook = nbformat.read(NOTEBOOK, as_version=4)
    nbformat.validate(notebook)
    for cell in notebook.cells:
        if cell.cell_type == "code":
            assert cell.outputs == [] and cell.execution_count is None, cell.source[:60]


@pytest.mark.slow
def test_the_notebook_runs_from_a_fresh_runs_logs(tmp_path, run_on_simulated_rig, monkeypatch):
    nbformat = pytest.importorskip("nbformat")
    nbclient = pytest.importorskip("nbclient")
    pytest.importorskip("ipykernel")
    logs = tmp_path / "logs"
    for protocol, run_id in (
        ("joint_estimation.yaml", "example-default"),
        ("link_validation.yaml", "example-link"),
    ):
        report, _ = run_on_simulated_rig(PROTOCOLS / protocol, logs, run_id=run_id, seed=0)
        assert report.exit_code == 0
    monkeypatch.setenv("RIG_EXAMPLE_LOGS", str(logs))
    monkeypatch.setenv("MPLBACKEND", "Agg")
    notebook = nbformat.read(NOTEBOOK, as_version=4)
    started = time.monotonic()
    nbclient.NotebookClient(
        notebook,
        timeout=int(MAX_SECONDS),
        kernel_name="python3",
        resources={"metadata": {"path": str(tmp_path)}},
    ).execute()
    elapsed_s = time.monotonic() - started
    assert elapsed_s < MAX_SECONDS
    errors = [
        o for c in notebook.cells if c.cell_type == "code" for o in c.outputs if o.output_type == "error"
    ]
    assert errors == []
    last = notebook.cells[-1].outputs[0]["data"]["text/plain"]
    assert "example-default" in last and "example-link" in last and "both runs, one fit" in last
