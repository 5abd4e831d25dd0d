"""examples/deepracer_rl.ipynb runs as written, with a small budget: Ray rollout workers, the S3 store
(moto's real server on 127.0.0.1), the live metrics chart, evaluation and the car's archive."""

from __future__ import annotations

import re
import socket
from pathlib import Path

import pytest

nbformat = pytest.importorskip("nbformat")
nbclient = pytest.importorskip("nbclient")
pytest.importorskip("ipykernel")
pytest.importorskip("ray")
pytest.importorskip("tensorflow")
moto_server = pytest.importorskip("moto.server")

NOTEBOOK = Path(__file__).resolve().parents[2] / "examples" / "deepracer_rl.ipynb"


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def _with_small_budget(notebook, work: Path):
    """The notebook with its parameters cell set for a test (the cell tagged "parameters")."""
    cell = next(c for c in notebook.cells if "parameters" in c.metadata.get("tags", []))
    # 20 s: two iterations of 4 episodes on a loaded 2-core machine (~10 s each; the test asks for one)
    cell.source += (f'\nTRAINING_TIME = "20s"\nWORKERS = 2\nNUM_EPISODES_BETWEEN_TRAINING = 4\nEVALUATION_TRIALS = 1'
                    f'\nWORK_FOLDER = "{work}"\n')
    return notebook


def test_the_notebook_runs_as_written(tmp_path, monkeypatch):
    port = _free_port()
    server = moto_server.ThreadedMotoServer(ip_address="127.0.0.1", port=port, verbose=False)
    server.start()
    try:
        monkeypatch.setenv("AWS_ENDPOINT_URL", f"http://127.0.0.1:{port}")
        monkeypatch.setenv("AWS_ACCESS_KEY_ID", "notebook")
        monkeypatch.setenv("AWS_SECRET_ACCESS_KEY", "notebook")
        monkeypatch.setenv("AWS_DEFAULT_REGION", "us-east-1")
        monkeypatch.setenv("LAPLAB_STORE", "s3://deepracer-notebook/models")
        monkeypatch.setenv("LAPLAB_HOME", str(tmp_path / "home"))
        notebook = _with_small_budget(nbformat.read(NOTEBOOK, as_version=4), tmp_path / "files")
        nbclient.NotebookClient(notebook, timeout=600, kernel_name="python3",
                                resources={"metadata": {"path": str(tmp_path)}}).execute()
    finally:
        server.stop()
    outputs = {i: "".join(o.get("text", "") for o in cell.get("outputs", []))
               for i, cell in enumerate(notebook.cells) if cell.cell_type == "code"}
    text = "\n".join(outputs.values())
    assert "models go to s3://deepracer-notebook/models" in text
    assert "Completed" in text, text[-3000:]
    trained = re.search(r"reached the time limit after (\d+) iterations?", text)  # the job's last words
    assert trained and int(trained.group(1)) >= 1, text[-3000:]
    assert len(re.findall(r"^trial \d+: ", text, re.M)) == 1  # EVALUATION_TRIALS
    charts = [o for cell in notebook.cells for o in cell.get("outputs", []) if "image/png" in o.get("data", {})]
    assert len(charts) >= 2  # the live chart and the final one
    archives = list((tmp_path / "files").glob("*.tar.gz"))
    assert len(archives) == 1 and archives[0].stat().st_size > 1_000_000
