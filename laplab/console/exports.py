"""Download and import for the console: ``laplab export`` / ``laplab import`` in a child process
with a clean environment and limits (torch stays out of the server; archives are untrusted)."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import BinaryIO

from laplab.jobs.confinement import JobLimits, clean_environment, limits_preexec
from laplab.settings import current_settings

EXPORT_TIMEOUT_S = 300.0
MAX_IMPORT_BYTES = 2 * 1024 ** 3


class ExportError(ValueError):
    """An export or import that laplab refused, with laplab's message."""


def _laplab(args: list[str], cwd: Path) -> dict:
    """Run ``laplab ARGS`` in a limited child process and return its outcome (the JSON it writes to
    ``$LAPLAB_RESULT_FILE``: :mod:`laplab.commands.outcome`); its refusal as an :class:`ExportError`."""
    from laplab.commands.outcome import RESULT_FILE_ENV
    with tempfile.TemporaryDirectory(prefix="laplab-outcome-") as scratch:
        result_file = Path(scratch) / "outcome.json"
        env = clean_environment({**current_settings().to_env(), RESULT_FILE_ENV: str(result_file)}, sandboxed=False)
        try:
            done = subprocess.run([sys.executable, "-m", "laplab.cli", *args], capture_output=True, env=env,
                                  cwd=cwd, timeout=EXPORT_TIMEOUT_S,
                                  preexec_fn=limits_preexec(JobLimits.console(cpu_seconds=600)))
        except subprocess.TimeoutExpired:
            raise ExportError(f"`laplab {args[0]}` did not finish within {EXPORT_TIMEOUT_S:g} s") from None
        try:
            outcome = json.loads(result_file.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            outcome = None
    if outcome is None:
        raise ExportError(f"`laplab {args[0]}` ended without an answer (exit status {done.returncode}: it ran out "
                          "of time or memory, or crashed)")
    if not outcome.get("ok") or done.returncode != 0:
        raise ExportError(outcome.get("error") or f"`laplab {args[0]}` failed (exit status {done.returncode})")
    return outcome


def export(name: str, fmt: str) -> tuple[Path, Path]:
    """(the file to send, the temporary folder to remove afterwards)."""
    folder = Path(tempfile.mkdtemp(prefix="laplab-export-"))
    try:
        if fmt == "tar":
            out = folder / f"{name}.tar.gz"
            _laplab(["export", name, "--format", "tar", "--out", str(out)], folder)
            return out, folder
        onnx_dir = folder / f"{name}-onnx"
        _laplab(["export", name, "--format", "onnx", "--out", str(onnx_dir)], folder)
        out = folder / f"{name}-onnx.tar.gz"
        import tarfile
        with tarfile.open(out, "w:gz") as tar:
            for path in sorted(onnx_dir.iterdir()):
                tar.add(path, arcname=path.name)
        return out, folder
    except BaseException:
        shutil.rmtree(folder, ignore_errors=True)
        raise


def import_archive(stream: BinaryIO, name: str | None, service, user, filename: str | None = None) -> str:
    """Import an uploaded archive as ``name`` (default: the exported name) owned by ``user``: a
    ``laplab export`` archive or a DeepRacer model folder as .tar.gz or .zip (``filename`` says which)."""
    from laplab.store.layout import ModelNameError, validate_model_name
    folder = Path(tempfile.mkdtemp(prefix="laplab-import-"))
    try:
        path = folder / ("upload.zip" if (filename or "").lower().endswith(".zip") else "upload.tar.gz")
        with open(path, "wb") as out:
            copied = 0
            while chunk := stream.read(1 << 20):
                copied += len(chunk)
                if copied > MAX_IMPORT_BYTES:
                    raise ExportError(f"the archive is larger than {MAX_IMPORT_BYTES >> 30} GiB")
                out.write(chunk)
        shown = name
        if name:
            from laplab.console.service import model_key
            try:
                validate_model_name(name)
                name = validate_model_name(model_key(user, name))
            except ModelNameError as exc:
                raise ExportError(str(exc)) from None
            if name in service.owners():
                raise ExportError(f"you already have a model named {shown!r}; import it under another name")
        elif not user.is_admin:
            raise ExportError("name the model to import (model names are per user)")
        imported = _laplab(["import", str(path)] + (["--name", name] if name else []), folder)["model"]
        service.store.claim_model(imported, user.id, "imported")
        return imported
    finally:
        shutil.rmtree(folder, ignore_errors=True)
