"""Regenerate laplab's built-in track files from their recipes in ``laplab/track/designs.py``.

Writes ``laplab/track/data/<name>.npy`` (DeepRacer route, (N, 6) float64) for every design and
``laplab/track/data/builtin.json`` ({name: {description, width, length}}, width and length in m).
The output is byte-stable: running the script twice gives identical files.

Usage: ``python3 scripts/make_builtin_tracks.py [--check]``; ``--check`` writes nothing and exits 1
if a committed file differs from what the recipes build now.
"""

from __future__ import annotations

import argparse
import io
import json
import sys
from pathlib import Path

import numpy as np

REPO_ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO_ROOT))

from laplab.track.designs import DESIGNS, build_route, route_length  # noqa: E402

DATA_DIR = REPO_ROOT / "laplab" / "track" / "data"


def builtin_files() -> dict[str, bytes]:
    """File name -> exact bytes of every generated file."""
    files: dict[str, bytes] = {}
    catalogue = {}
    for name, design in sorted(DESIGNS.items()):
        route = build_route(design)
        buffer = io.BytesIO()
        np.save(buffer, route, allow_pickle=False)
        files[f"{name}.npy"] = buffer.getvalue()
        catalogue[name] = {"description": design.description, "width": design.width,
                           "length": round(route_length(route), 3)}
    files["builtin.json"] = (json.dumps(catalogue, indent=2, sort_keys=True) + "\n").encode()
    return files


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="only compare with the committed files")
    args = parser.parse_args(argv)
    stale = []
    for file_name, content in builtin_files().items():
        path = DATA_DIR / file_name
        if path.is_file() and path.read_bytes() == content:
            continue
        stale.append(file_name)
        if not args.check:
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_bytes(content)
    verb = "out of date" if args.check else "written"
    print(f"{len(stale)} file(s) {verb}: {', '.join(stale) or 'none'}")
    return 1 if (args.check and stale) else 0


if __name__ == "__main__":
    raise SystemExit(main())
