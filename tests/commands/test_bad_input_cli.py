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
