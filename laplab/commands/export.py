"""``laplab export`` (a model as a ``.tar.gz`` archive, an ONNX policy, the physical car's TensorFlow
tar.gz or the DeepRacer console's import folder) and ``laplab import``."""

from __future__ import annotations

import argparse
import json
import tempfile
from dataclasses import dataclass
from pathlib import Path

from laplab.errors import UserError
from laplab.commands.outcome import record  # what the console reads (the imported model's name)

PARITY_TOLERANCE = 1e-4  # max |ONNX - torch| accepted by the export's self-check


def register(subparsers: argparse._SubParsersAction) -> None:
    export = subparsers.add_parser(
        "export", help="export a model: archive (tar.gz), ONNX policy, the car's model.pb tar.gz, console folder",
        description="Write model MODEL as a .tar.gz archive that `laplab import` restores (weights of one "
                    "checkpoint, model_metadata.json, hyperparameters, reward function, laplab.json, metrics), "
                    "its policy as an ONNX graph plus model_metadata.json (laplab.runtime.OnnxPolicy runs it), "
                    "the physical DeepRacer car's tar.gz (TensorFlow model.pb with DeepRacer's node names + "
                    "model_metadata.json; --format car) or the DeepRacer console's import layout "
                    "(--format console). car and console need `pip install 'laplab[deepracer]'`. See docs/car.md.")
    export.add_argument("model", metavar="MODEL", help="name of the model")
    from laplab.train.request import EXPORT_FORMATS, ExportRequest
    export.add_argument("--format", choices=EXPORT_FORMATS, default="tar", help="what to write (default: tar)")
    export.add_argument("--checkpoint", default=ExportRequest.checkpoint,
                        help=f"'{ExportRequest.checkpoint}' (default), 'last' or a checkpoint file name")
    export.add_argument("--full-state", action="store_true",
                        help="tar: add the optimizer state and target networks (with --checkpoint last) so "
                             "`laplab train --resume` continues exactly on another machine; by default an "
                             "archive carries the weights only")
    export.add_argument("--out", type=_out_path, help="tar, car: the archive file or a folder for it (default "
                                                      "./MODEL.tar.gz); onnx: the folder (default ./MODEL-onnx); "
                                                      "console: a new or empty folder (default ./MODEL-console) or "
                                                      "an S3 prefix s3://BUCKET/PREFIX (as dr-upload-model uploads)")
    from laplab.commands.store_option import add_store_option
    add_store_option(export)
    export.set_defaults(func=export_command)

    imp = subparsers.add_parser(
        "import", help="add a model: a `laplab export` archive, or a DeepRacer model (folder, tar.gz, zip, "
                       "s3:// prefix, model.pb)",
        description="Add a model to your models, atomically, after checking it. SOURCE is a `laplab export` "
                    "archive, or a DeepRacer model: the folder the DeepRacer console, DeepRacer on AWS or "
                    "`laplab export --format console` writes (model_metadata.json, reward_function.py, "
                    "ip/hyperparameters.json, model/ with rl_coach's TensorFlow checkpoint), as a folder, .tar.gz "
                    "or .zip; a deepracer-for-cloud prefix s3://BUCKET/PREFIX (endpoint: $AWS_ENDPOINT_URL); or a "
                    "car's model.pb with its model_metadata.json beside it (evaluates and races; cannot be "
                    "trained further). The reward function that comes with a model is not trusted until you say "
                    "so (--trust-reward). See docs/import.md.")
    imp.add_argument("file", metavar="SOURCE", help="archive, model folder, .zip, model.pb or s3://BUCKET/PREFIX")
    imp.add_argument("--name", help="name of the new model (default: the exported model's name, or the folder's / "
                                    "file's / prefix's last part)")
    imp.set_defaults(func=import_command)


def _out_path(text: str) -> Path | str:
    """``--out``: a local path, or an ``s3://`` URL kept as text (a Path would fold its '//')."""
    return text if text.startswith("s3://") else Path(text)


def _upload_console_folder(folder: Path, url: str) -> int:
    """Upload the console layout in ``folder`` to the S3 prefix ``url`` (endpoint: AWS_ENDPOINT_URL):
    the checkpoint's data first, the small files that name it (TensorFlow's state file,
    .coach_checkpoint, deepracer_checkpoints.json) last, so that an importer never sees a name before
    its data. Returns the number of files."""
    from laplab.store.s3 import ObjectStore, StoreError, parse_store_url
    naming = ("model/checkpoint", "model/.coach_checkpoint", "model/deepracer_checkpoints.json")
    files = sorted((p.relative_to(folder).as_posix() for p in folder.rglob("*") if p.is_file()),
                   key=lambda rel: (rel in naming, naming.index(rel) if rel in naming else 0, rel))
    try:
        store = ObjectStore(parse_store_url(url))
        store.check()
        for rel in files:
            store.put_file(store.location.key(rel), folder / rel)
    except StoreError as exc:
        raise UserError(str(exc)) from None
    return len(files)


@dataclass(frozen=True)
class OnnxExport:
    onnx_path: Path
    metadata_path: Path
    parity_error: float | None  # max |ONNX - torch| on random observations (None: onnxruntime absent)


def export_model_onnx(name: str, checkpoint: str = "best", out_dir: str | Path | None = None) -> OnnxExport:
    """Write ``model.onnx`` and ``model_metadata.json`` of model ``name``'s policy at ``checkpoint``
    into ``out_dir`` (default ``./<name>-onnx``), and check the graph against torch."""
    try:
        from laplab.agents.onnx_export import model_parity_error, model_to_onnx
        from laplab.train.policy import load_model_policy
    except ImportError as exc:
        raise UserError(f"ONNX export needs torch and onnx ({exc}); install them with "
                        "`pip install torch onnx onnxruntime`.") from None
    from laplab.store.atomic import atomic_write_bytes, atomic_write_text
    try:
        import onnx  # noqa: F401  (model_to_onnx imports it; fail early with a clear message)
    except ImportError:
        raise UserError("ONNX export needs the onnx package: `pip install onnx onnxruntime`.") from None

    policy = load_model_policy(name, checkpoint)
    metadata_text = json.dumps(policy.folder.read_model_metadata(), indent=2) + "\n"
    graph = model_to_onnx(policy.network, policy.spec, metadata_text)
    try:
        error = model_parity_error(graph, policy.network, policy.spec)
    except ImportError:
        error = None
    if error is not None and error > PARITY_TOLERANCE:
        raise UserError(f"the ONNX graph of {name!r} differs from the torch policy by {error:.3g} "
                        f"(> {PARITY_TOLERANCE}); nothing was written. Please report this as a bug.")
    folder = Path(out_dir) if out_dir is not None else Path.cwd() / f"{name}-onnx"
    onnx_path = atomic_write_bytes(folder / "model.onnx", graph)
    metadata_path = atomic_write_text(folder / "model_metadata.json", metadata_text)
    return OnnxExport(onnx_path, metadata_path, error)


def export_deepracer(args: argparse.Namespace) -> int:
    """--format car / console (laplab.export; TensorFlow needed)."""
    try:
        from laplab.export.car import CarExportError, export_car
        from laplab.export.console import export_console
        import tensorflow  # noqa: F401  (fail early, with the install line)
    except ImportError as exc:
        raise UserError(f"--format {args.format} needs TensorFlow ({exc}); install it with "
                        "`pip install 'laplab[deepracer]'` (tensorflow-cpu, openvino).") from None
    try:
        if args.format == "car":
            path, graph = export_car(args.model, args.checkpoint, args.out)
            print(f"wrote {path} ({path.stat().st_size / 1e6:.1f} MB: agent/model.pb from {graph.checkpoint}, "
                  f"model_metadata.json; max |TensorFlow - torch| = {graph.parity_error:.1e}). Upload it on the "
                  "car's device console (Models > Upload).")
        elif isinstance(args.out, str):  # s3://BUCKET/PREFIX: written here first, checked, then uploaded
            with tempfile.TemporaryDirectory(prefix="laplab-console-") as staging:
                result = export_console(args.model, args.checkpoint, Path(staging) / args.model)
                count = _upload_console_folder(result.folder, args.out)
            print(f"uploaded {count} files to {args.out.rstrip('/')}/ (model/model_*.pb and rl_coach's TensorFlow "
                  f"checkpoint model/{result.graph.checkpoint}.* ; max |TensorFlow - torch| = "
                  f"{result.graph.parity_error:.1e}, |checkpoint - model.pb| = {result.checkpoint_error:.1e})")
        else:
            result = export_console(args.model, args.checkpoint, args.out)
            print(f"wrote {len(result.files)} files into {result.folder} (model/model_*.pb and rl_coach's "
                  f"TensorFlow checkpoint model/{result.graph.checkpoint}.* ; max |TensorFlow - torch| = "
                  f"{result.graph.parity_error:.1e}, |checkpoint - model.pb| = {result.checkpoint_error:.1e})")
        for note in (result.limitations if args.format == "console" else ()):
            print(f"note: {note}")
    except (CarExportError, FileNotFoundError) as exc:
        raise UserError(str(exc)) from None
    return 0


def check_out_path(out: Path | str | None, option: str = "--out") -> None:
    """:class:`UserError` when ``out`` cannot be written: a local folder above it is a regular file, or
    an ``s3://`` URL or ``AWS_ENDPOINT_URL`` that is malformed (checked before anything is pulled,
    converted or written)."""
    if isinstance(out, str):
        from laplab.store.s3 import StoreError, endpoint_url, parse_store_url
        try:
            parse_store_url(out)
            endpoint_url()
        except StoreError as exc:
            raise UserError(str(exc), field=exc.field or option) from None
        return
    if not isinstance(out, Path):
        return
    for parent in out.absolute().parents:
        if parent.exists():
            if not parent.is_dir():
                raise UserError(f"{option} {out}: {parent} is a file, not a folder, so nothing can be written "
                                f"below it; give a path in an existing folder (or one laplab may create).",
                                field=option)
            return


def export_command(args: argparse.Namespace) -> int:
    from laplab.commands.store_option import store_session, without_traces
    from laplab.train.request import ExportRequest, as_cli_error
    try:  # the ranges and messages of the console's export jobs
        ExportRequest(format=args.format, checkpoint=args.checkpoint)
    except UserError as exc:
        raise as_cli_error(exc) from None
    check_out_path(args.out)
    with store_session(args, "export") as store:
        if store:
            store.pull(args.model, (args.checkpoint,), without_traces)
        return _export(args)


def _export(args: argparse.Namespace) -> int:
    from laplab.store.archive import ArchiveError
    from laplab.train.archive import export_model_archive
    if isinstance(args.out, str) and args.format != "console":
        raise UserError(f"--out {args.out}: an S3 prefix takes --format console (the DeepRacer console's "
                        "import layout); write the other formats to a local file or folder.")
    if args.format in ("car", "console"):
        return export_deepracer(args)
    if args.format == "onnx":
        result = export_model_onnx(args.model, args.checkpoint, args.out)
        check = ("" if result.parity_error is None
                 else f" (max |ONNX - torch| = {result.parity_error:.1e} on 16 random observations)")
        print(f"wrote {result.onnx_path} and {result.metadata_path.name}{check}")
        return 0
    try:
        path = export_model_archive(args.model, args.checkpoint, args.out, full_state=args.full_state)
    except ArchiveError as exc:
        raise UserError(str(exc)) from None
    print(f"wrote {path} ({path.stat().st_size / 1e6:.1f} MB)")
    return 0


def import_command(args: argparse.Namespace) -> int:
    from laplab.export.deepracer_import import is_deepracer_source
    if is_deepracer_source(args.file):
        return import_deepracer(args)
    from laplab.store.archive import ArchiveError
    from laplab.train.archive import import_model_archive
    try:
        imported = import_model_archive(Path(args.file), args.name)
    except ArchiveError as exc:
        raise UserError(str(exc)) from None
    print(f"imported model {imported.name!r} (checkpoint {imported.checkpoint}) into {imported.folder.root}")
    _reward_note(imported.name, imported.folder.reward_function)
    record(model=imported.name, checkpoint=imported.checkpoint, trainable=True)
    return 0


def _reward_note(name: str, reward_function: Path) -> None:
    print(f"note: the model comes with a reward function ({reward_function}); it is Python code "
          f"and will run with your permissions if you train this model (`laplab train --resume {name}`, "
          f"`laplab clone {name} NEW`). Read it first: those commands ask for --trust-reward once, "
          f"or clone with your own --reward FILE. Evaluating and exporting the model run no code from it.")


def import_deepracer(args: argparse.Namespace) -> int:
    """A DeepRacer model (laplab.export.deepracer_import): rl_coach checkpoint or model.pb."""
    from laplab.export.deepracer_import import import_deepracer_model
    imported = import_deepracer_model(args.file, args.name)
    kind = "rl_coach checkpoint" if imported.trainable else "frozen graph"
    print(f"imported model {imported.name!r} from {args.file} ({kind} {imported.source_checkpoint}, now laplab's "
          f"checkpoint {imported.checkpoint}) into {imported.folder.root}")
    for note in imported.notes:
        print(f"note: {note}")
    if imported.trainable:
        _reward_note(imported.name, imported.folder.reward_function)
    record(model=imported.name, checkpoint=imported.checkpoint, trainable=imported.trainable, notes=list(imported.notes))
    return 0
