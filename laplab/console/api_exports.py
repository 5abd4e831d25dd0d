"""Downloads for the car, built as jobs: ``POST /api/models/{name}/exports {format}`` starts one
(TensorFlow is heavy: it runs in a confined worker process, never in the server), its state is
``GET /api/models/{name}/exports/{id}`` and its file ``GET .../exports/{id}/file``.

``format``: ``car`` (the physical car's tar.gz: ``agent/model.pb`` + ``model_metadata.json``) or
``console`` (the DeepRacer console's import layout, as a tar.gz). See docs/car.md.
"""

from __future__ import annotations

import importlib.util
from typing import Literal

from fastapi import APIRouter, Depends, HTTPException, Request
from fastapi.responses import FileResponse
from pydantic import BaseModel, ConfigDict, Field

from laplab.console.api import _service, bad_request, own_model
from laplab.console.auth import current_user
from laplab.console.outcomes import without_paths
from laplab.jobs.db import Job, User
from laplab.jobs.runner import job_folder, models_dir
from laplab.train.request import JOB_EXPORT_FORMATS, ExportRequest

router = APIRouter(prefix="/api")
EXPORT_STATUS = {"queued": "queued", "running": "running", "stopping": "running", "done": "done"}
FILE_NAMES = {"car": "{name}.tar.gz", "console": "{name}-console.tar.gz"}


class Export(BaseModel):
    """An export job: laplab.train.request.ExportRequest's fields and defaults (its checks give the errors)."""
    model_config = ConfigDict(extra="forbid")
    format: Literal[JOB_EXPORT_FORMATS] = ExportRequest.format
    checkpoint: str = Field(ExportRequest.checkpoint, max_length=200)


def tensorflow_missing() -> str | None:
    """The message when this machine cannot build the car's format, else None."""
    if importlib.util.find_spec("tensorflow") is None:
        return ("the car's format needs TensorFlow on the console's machine: install it there with "
                "`pip install 'laplab[deepracer]'` (tensorflow-cpu, openvino) and restart `laplab serve`")
    return None


def onnx_missing() -> str | None:
    """The message when this machine cannot build the ONNX download, else None."""
    if importlib.util.find_spec("onnx") is None:
        return ("the ONNX download needs the onnx package on the console's machine: install it there with "
                "`pip install 'laplab[export]'` and restart `laplab serve`")
    return None


def _format_refused(name: str, fmt: str) -> str | None:
    """Why model ``name`` cannot be built in ``fmt`` ('car' / 'console'), else None: the model's own
    reason (a STATE model is not a camera model) before the machine's (no TensorFlow)."""
    from laplab.errors import UserError
    from laplab.export.car import CAR_SENSORS, CONSOLE_SENSORS, check_model_exportable
    try:
        check_model_exportable(name, *((CAR_SENSORS, "the DeepRacer car") if fmt == "car"
                                       else (CONSOLE_SENSORS, "the DeepRacer console")))
    except UserError as exc:
        return without_paths(str(exc))
    return tensorflow_missing()


def download_blocks(name: str, status: str) -> dict[str, str | None]:
    """For each download button of model ``name`` (its key), why it cannot work now (None: it can):
    the page disables the button and shows the reason."""
    if status in ("training", "queued", "stopping"):
        busy = "the model is training: download it when its training has ended"
        return {"tar": busy, "onnx": busy, "car": busy, "console": busy}
    if not (models_dir() / name / "model" / "deepracer_checkpoints.json").exists():
        none = "the model has no checkpoint yet"
        return {"tar": none, "onnx": none, "car": none, "console": none}
    return {"tar": None, "onnx": onnx_missing(), "car": _format_refused(name, "car"),
            "console": _format_refused(name, "console")}


def export_view(job: Job) -> dict:
    result = job.result or {}
    out = {"id": job.id, "status": EXPORT_STATUS.get(job.status, "failed"), "format": job.params.get("format"),
           "checkpoint": result.get("checkpoint") or job.params.get("checkpoint"), "created": job.created,
           "finished": job.finished, "error": job.error, "size": result.get("size"), "url": None}
    if out["status"] == "done" and result.get("file"):
        out["url"] = f"/api/models/{job.model}/exports/{job.id}/file"
    return out


def export_file(job: Job):
    """The file a finished export wrote (404 when gone)."""
    name = (job.result or {}).get("file")
    path = job_folder(job.id) / "export" / name if name else None
    if path is None or path.name != name or not path.is_file():
        raise HTTPException(404, f"export {job.id} of {job.model!r} has no file (it failed or was removed)")
    return FileResponse(path, media_type="application/gzip", filename=path.name)


def _export_job(request: Request, name: str, job_id: int) -> Job:
    job = _service(request).store.job(job_id)
    if job is None or job.model != name or job.kind != "export":
        raise HTTPException(404, f"no export {job_id} of {name!r}")
    return job


@router.post("/models/{name}/exports", status_code=202)
def start_export(name: str, body: Export, request: Request, user: User = Depends(current_user)) -> dict:
    name = own_model(request, name, user)
    service = _service(request)
    active = service.active_job(name)
    if active is not None and active.kind not in ("evaluate", "export"):
        raise HTTPException(409, f"{name!r} is training: download it for the car when its training has ended")
    if not (models_dir() / name / "model" / "deepracer_checkpoints.json").exists():
        raise HTTPException(409, f"{name!r} has no checkpoint to export yet")
    from laplab.errors import UserError
    try:
        export = ExportRequest.from_mapping(body.model_dump()).as_job()
    except UserError as exc:
        raise bad_request(str(exc), exc.field) from None
    refused = _format_refused(name, export.format)  # a STATE model says so before TensorFlow is asked for
    if refused:
        raise bad_request(refused, "format")
    job = service.submit("export", name, service.owners()[name], export.to_mapping())
    return export_view(job)


@router.get("/models/{name}/exports")
def list_exports(name: str, request: Request, user: User = Depends(current_user)) -> list[dict]:
    name = own_model(request, name, user)
    return [export_view(j) for j in _service(request).store.jobs(model=name, kind=("export",))]


@router.get("/models/{name}/exports/{job_id}")
def get_export(name: str, job_id: int, request: Request, user: User = Depends(current_user)) -> dict:
    name = own_model(request, name, user)
    return export_view(_export_job(request, name, job_id))


@router.get("/models/{name}/exports/{job_id}/file")
def get_export_file(name: str, job_id: int, request: Request, user: User = Depends(current_user)):
    name = own_model(request, name, user)
    return export_file(_export_job(request, name, job_id))


def latest_export(request: Request, name: str, fmt: str):
    """``download?format=car|console``: the newest finished export of that format, if it is not
    older than the model's checkpoints (else 409, saying how to build one)."""
    checkpoints = models_dir() / name / "model" / "deepracer_checkpoints.json"
    done = [j for j in _service(request).store.jobs(model=name, kind=("export",), status=("done",))
            if j.params.get("format") == fmt]
    if done and (job := done[-1]).finished and checkpoints.exists() and job.finished >= checkpoints.stat().st_mtime:
        return export_file(job)
    raise HTTPException(409, {"message": f"the {fmt} format of {name!r} is built as a job: POST "
                                         f"/api/models/{name}/exports {{\"format\": \"{fmt}\"}}, then download "
                                         "its file when it is done (the model page's Download for the car does this)",
                              "field": "format"})
