"""Issue 31, bad input on the command line: one paragraph naming the option, file, key or field,
exit status 2, no traceback, nothing written. One tiny model is trained once for the module."""

import json
import shutil

import pytest

from laplab.cli import main
from laplab.store.layout import model_folder


@pytest.fixture(scope="module")
def home(tmp_path_factory):
    root = tmp_path_factory.mktemp("home")
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("LAPLAB_HOME", str(root))
        assert main(["train", "--name", "base", "--max-episodes", "1", "--quiet"]) == 0
    return root


@pytest.fixture
def laplab_home(home, monkeypatch):
    monkeypatch.setenv("LAPLAB_HOME", str(home))
    monkeypatch.delenv("LAPLAB_STORE", raising=False)
    return home


def _copy_model(name, new):
    shutil.copytree(model_folder(name).root, model_folder(new).root)
    return model_folder(new)


def _refused(capsys, argv, *needles):
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err
    for needle in needles:
        assert needle in err, err
    return err


def test_export_out_below_a_regular_file(laplab_home, tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    for fmt in ("tar", "onnx", "car"):
        _refused(capsys, ["export", "base", "--format", fmt, "--out", str(blocker / "x.tar.gz")],
                 "--out", f"{blocker} is a file")
    assert blocker.read_text() == "x"


def test_store_with_an_endpoint_that_is_not_a_url(laplab_home, monkeypatch, capsys):
    monkeypatch.setenv("AWS_ENDPOINT_URL", "not a url")
    _refused(capsys, ["evaluate", "base", "--store", "s3://bucket/models"], "AWS_ENDPOINT_URL", "'not a url'")
    _refused(capsys, ["export", "base", "--format", "console", "--out", "s3://bucket/models"], "AWS_ENDPOINT_URL")


def _edit_json(path, change):
    data = json.loads(path.read_text())
    change(data)
    path.write_text(json.dumps(data))


@pytest.mark.parametrize("change, key", [
    (lambda d: d.update(sensor=["FRONT_FACING_CAMERA"]), "'sensor'"),
    (lambda d: d["action_space"].pop(), "'action_space'"),
    (lambda d: d.update(action_space={"steering_angle": {"low": -30, "high": 30},
                                      "speed": {"low": 1, "high": 4}}, action_space_type="continuous"),
     "'action_space"),
])
def test_model_metadata_edited_after_training(laplab_home, tmp_path, capsys, change, key):
    folder = _copy_model("base", "edited")
    try:
        _edit_json(folder.model_metadata, change)
        before = sorted(p.name for p in folder.root.rglob("*"))
        for argv in (["evaluate", "edited"], ["export", "edited", "--out", str(tmp_path / "e.tar.gz")],
                     ["export", "edited", "--format", "onnx", "--out", str(tmp_path / "onnx")]):
            _refused(capsys, argv, str(folder.model_metadata), key, "changed after training")
        assert sorted(p.name for p in folder.root.rglob("*")) == before
        assert not (tmp_path / "e.tar.gz").exists() and not (tmp_path / "onnx").exists()
    finally:
        shutil.rmtree(folder.root)


def test_resume_with_garbage_hyperparameters_json(laplab_home, capsys):
    folder = _copy_model("base", "garbage-hp")
    try:
        folder.hyperparameters.write_text("{not json")
        _refused(capsys, ["train", "--resume", "garbage-hp", "--max-episodes", "40"],
                 str(folder.hyperparameters))
        folder.hyperparameters.write_text(json.dumps({"num_epochs": 7}))
        _refused(capsys, ["train", "--resume", "garbage-hp", "--max-episodes", "40"],
                 str(folder.hyperparameters), "'num_epochs'")
    finally:
        shutil.rmtree(folder.root)


def test_resume_when_every_checkpoint_file_is_gone(laplab_home, capsys):
    folder = _copy_model("base", "no-ckpt")
    try:
        for path in folder.model_dir.glob("*.ckpt*"):
            path.unlink()
        _refused(capsys, ["train", "--resume", "no-ckpt", "--max-episodes", "40"],
                 str(folder.deepracer_checkpoints), "no checkpoint file")
        assert not list(folder.model_dir.glob("*.ckpt*"))
    finally:
        shutil.rmtree(folder.root)


@pytest.mark.parametrize("option, value", [("--hyperparameters", '{"num_epochs": 5}'),
                                           ("--model-metadata", "model_metadata.json")])
def test_resume_refuses_what_it_would_ignore(laplab_home, capsys, option, value):
    if option == "--model-metadata":
        value = str(model_folder("base").model_metadata)
    _refused(capsys, ["train", "--resume", "base", option, value], option, "clone")


def test_hyperparameters_given_as_a_json_list(laplab_home, capsys):
    _refused(capsys, ["train", "--name", "list-hp", "--hyperparameters", "[1, 2]"],
             "--hyperparameters", "JSON object")
    assert not model_folder("list-hp").exists()


def test_stack_size_out_of_range(laplab_home, capsys):
    _refused(capsys, ["train", "--name", "big-stack", "--hyperparameters", '{"stack_size": 1000000}'],
             "'stack_size'", "from 1 to 8")
    assert not model_folder("big-stack").exists()


def test_too_many_actions(laplab_home, tmp_path, capsys):
    path = tmp_path / "model_metadata.json"
    path.write_text(json.dumps({"action_space": [{"steering_angle": 0, "speed": 1.0}] * 65}))
    _refused(capsys, ["train", "--name", "many", "--model-metadata", str(path)], str(path), "1 to 64")
    path.write_text(json.dumps({"action_space": [{"steering_angle": 0, "speed": 1.0}]}) + " " * (300 << 10))
    _refused(capsys, ["train", "--name", "many", "--model-metadata", str(path)], str(path), "KiB")
    assert not model_folder("many").exists()


def test_report_on_a_simtrace_csv_that_is_not_text(laplab_home, tmp_path, capsys):
    folder = _copy_model("base", "garbage-trace")
    try:
        (trace,) = folder.training_simtrace_dir.glob("*.csv")
        trace.write_bytes(trace.read_bytes()[:200] + bytes(range(128, 256)) * 4)
        _refused(capsys, ["report", "garbage-trace", "--out", str(tmp_path / "report")], str(trace), "UTF-8")
        folder.training_metrics.write_bytes(b"\xff\xfe{")
        _refused(capsys, ["report", "garbage-trace", "--out", str(tmp_path / "report")],
                 str(folder.training_metrics), "UTF-8")
    finally:
        shutil.rmtree(folder.root)
