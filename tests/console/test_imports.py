"""Importing DeepRacer models through the console's import route (``POST /api/models/import``, run
as ``laplab import`` in a confined child): a DeepRacer console-layout export as .tar.gz or .zip
becomes its importer's model; a damaged one is refused in one paragraph and leaves nothing."""

from __future__ import annotations

import io
import shutil
import tarfile
import zipfile

import pytest

pytest.importorskip("tensorflow", reason="the console export writes model.pb with tensorflow-cpu")


@pytest.fixture(scope="module")
def uploads(console, make_model, tmp_path_factory) -> dict[str, bytes]:
    """A DeepRacer console-layout export of a camera model, as .tar.gz and .zip bytes."""
    from laplab.export.console import export_console
    make_model("import-source", sensor=["FRONT_FACING_CAMERA"])
    folder = export_console("import-source", out=tmp_path_factory.mktemp("export") / "m").folder
    packed = {}
    buffer = io.BytesIO()
    with tarfile.open(fileobj=buffer, mode="w:gz") as tar:
        tar.add(folder, arcname="import-source")
    packed["tar.gz"] = buffer.getvalue()
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w") as archive:
        for path in sorted(p for p in folder.rglob("*") if p.is_file()):
            archive.write(path, path.relative_to(folder).as_posix())
    packed["zip"] = buffer.getvalue()
    shutil.rmtree(folder)
    return packed


def post(client, body: bytes, name: str, filename: str):
    return client.post("/api/models/import", files={"file": (filename, body)}, data={"name": name})


@pytest.mark.parametrize("kind", ["tar.gz", "zip"])
def test_an_uploaded_deepracer_model_becomes_the_importers(console, uploads, kind):
    name = f"imported-{kind.replace('.', '-')}"
    answer = post(console.admin, uploads[kind], name, f"my-model.{kind}")
    assert answer.status_code == 201, answer.text
    model = console.admin.get(f"/api/models/{name}").json()
    assert model["config"]["model_metadata"]["sensor"] == ["FRONT_FACING_CAMERA"]
    assert console.add_user(f"import-other-{kind}").get(f"/api/models/{name}").status_code == 404


def test_a_damaged_upload_is_one_paragraph_and_leaves_nothing(console, uploads):
    cut = post(console.admin, uploads["zip"][: len(uploads["zip"]) // 2], "cut-upload", "cut.zip")
    assert cut.status_code == 400 and cut.json()["detail"]["field"] == "file"
    assert "not a readable zip archive" in cut.json()["detail"]["message"]
    assert console.admin.get("/api/models/cut-upload").status_code == 404
    assert post(console.admin, uploads["zip"], "cut-upload", "whole.zip").status_code == 201  # the name is free
