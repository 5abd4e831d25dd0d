"""Evaluations on Ray (:mod:`laplab.cluster.evaluations`, what a console job does with ``laplab serve
--ray-address``): a Ray worker process drives the laps, the same laps as the local path, and the job's
process writes the result into the model's folder as a local evaluation does. One small local Ray,
one tiny model, one lap of the oval. (A console's race submission evaluated on a cluster joined through
Ray Client, as console jobs join: tests/console/test_ray_console.py.)"""

from __future__ import annotations

import os
import shutil

import pytest

ray = pytest.importorskip("ray")

from laplab.cluster.collector import connect_ray  # noqa: E402

from tests.console.conftest import create_tiny_model, numba_seed  # noqa: E402


@pytest.fixture(scope="module")
def local_ray(tmp_path_factory):
    """laplab's own local Ray (as `laplab train --workers 2` starts it), its workers compiling into a
    copy of the console tests' numba cache; yields the address a console job joins it by."""
    cache = tmp_path_factory.mktemp("ray-numba") / "numba"
    shutil.copytree(numba_seed(tmp_path_factory.getbasetemp()), cache)
    saved = os.environ.get("NUMBA_CACHE_DIR")
    os.environ["NUMBA_CACHE_DIR"] = str(cache)
    try:
        assert connect_ray(None, 2)
        yield ray.get_runtime_context().gcs_address
        ray.shutdown()
    finally:
        if saved is None:
            os.environ.pop("NUMBA_CACHE_DIR", None)
        else:
            os.environ["NUMBA_CACHE_DIR"] = saved


def test_the_ray_path_drives_the_same_laps_as_the_local_one(local_ray, tmp_path, monkeypatch):
    from laplab.cluster.evaluations import evaluate_model_on_ray
    from laplab.evaluate.trials import EvaluationSettings, evaluate_model, read_evaluation_summary
    from laplab.store.layout import model_folder
    monkeypatch.setenv("LAPLAB_HOME", str(tmp_path / "home"))
    create_tiny_model("tiny", sensor=["FRONT_FACING_CAMERA"])
    settings = EvaluationSettings(track="oval", trials=1, continuous=True, max_trial_time=60.0)
    said = []
    on_ray, stamp, where = evaluate_model_on_ray("tiny", settings, local_ray, said.append)
    local, _ = evaluate_model("tiny", settings)
    assert where["pid"] != os.getpid() and where["node_id"]  # a Ray worker drove, not this process
    assert [t.to_dict() for t in on_ray.trials] == [t.to_dict() for t in local.trials]
    assert said[0].startswith(f"evaluating 1 lap on the Ray cluster at {local_ray}")
    document = read_evaluation_summary(model_folder("tiny"), stamp)  # written as the local path writes it
    assert document["trials"] == [t.to_dict() for t in local.trials] and document["track"]["name"] == "oval"

