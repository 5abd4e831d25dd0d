"""``laplab tracks``: list, show, import and fetch DeepRacer tracks.

Only ``tracks fetch`` touches the network.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

from laplab.errors import UserError
from laplab.track import registry
from laplab.track.geometry import TrackError, load_route_file, remove_repeated_points, validate_route


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser("tracks", help="list, show, import and fetch tracks",
                                   description="List, draw, import and download DeepRacer tracks.")
    parser.set_defaults(func=lambda args: _print_help(parser))
    commands = parser.add_subparsers(dest="tracks_command", metavar="SUBCOMMAND")

    listing = commands.add_parser("list", help="table of known tracks",
                                  description="Built-in and user tracks with length, width and direction.")
    listing.add_argument("--json", action="store_true", help="print a JSON list instead of a table")
    listing.set_defaults(func=list_command)

    show = commands.add_parser("show", help="draw a track to a PNG",
                               description="Draw a track (borders, centre line, start line, driving "
                                           "direction) to an image file and print its path.")
    show.add_argument("name", metavar="NAME", help="track name or path to a .npy route")
    show.add_argument("--out", type=Path, help="image file to write (default: <name>.png in the current folder)")
    show.add_argument("--indices", action="store_true", help="label every waypoint with its index")
    show.add_argument("--reversed", action="store_true", help="draw the track driven the other way")
    show.set_defaults(func=show_command)

    imp = commands.add_parser("import", help="add a .npy route to your track folder",
                              description="Validate a DeepRacer route (.npy, shape (N, 6), closed loop) and "
                                          "copy it into $LAPLAB_HOME/tracks.")
    imp.add_argument("file", type=Path, metavar="FILE.npy")
    imp.add_argument("--name", help="track name (default: the file name without .npy)")
    imp.add_argument("--overwrite", action="store_true", help="replace a user track of the same name")
    imp.add_argument("--keep-repeated-points", action="store_true",
                     help="store the rows as given; by default repeated interior centre points are removed, "
                          "as current DeepRacer does on load")
    imp.set_defaults(func=import_command)

    fetch = commands.add_parser("fetch", help="download DeepRacer routes (network)",
                                description="Download the DeepRacer simapp's route files into your track "
                                            "folder; invalid routes are skipped with the reason.")
    fetch.add_argument("--base-url", help="folder URL holding <name>.npy files (default: $LAPLAB_TRACKS_URL, "
                                          "else the deepracer-simapp bundle/routes/ folder on GitHub)")
    fetch.add_argument("--names", help="comma-separated route names or official display names (\"Smile Speedway\"; "
                                       "default: the server's index.json, else the simapp names shipped with laplab)")
    fetch.add_argument("--dest", type=Path, help="folder to write into (default: $LAPLAB_HOME/tracks)")
    fetch.add_argument("--overwrite", action="store_true", help="replace existing files whose content differs")
    fetch.set_defaults(func=fetch_command)


def _print_help(parser: argparse.ArgumentParser) -> int:
    parser.print_help()
    return 2


def track_rows() -> list[dict]:
    """One dict per available track: name, length_m, width_m, direction, waypoints, source, path,
    default, and error (None, or why the file does not load)."""
    descriptions = _builtin_descriptions()
    rows = []
    for entry in registry.available_tracks():
        row = {"name": entry.name, "length_m": None, "width_m": None, "direction": None, "waypoints": None,
               "source": entry.source, "path": str(entry.path), "default": entry.name == registry.DEFAULT_TRACK,
               "description": descriptions.get(entry.name) if entry.source == "built-in" else None,
               "error": None}
        try:
            track = registry.load_track(entry.path)
        except TrackError as exc:
            row["error"] = str(exc)
        else:
            row.update(length_m=round(track.length, 3), width_m=round(track.nominal_width, 3),
                       direction=track.direction, waypoints=track.num_waypoints)
        rows.append(row)
    return rows


def _builtin_descriptions() -> dict[str, str]:
    path = registry.BUILTIN_DIR / "builtin.json"
    if not path.is_file():
        return {}
    return {name: info.get("description", "") for name, info in json.loads(path.read_text()).items()}


def list_command(args: argparse.Namespace) -> int:
    rows = track_rows()
    if args.json:
        print(json.dumps(rows, indent=2))
        return 0
    from rich.console import Console
    from rich.table import Table

    table = Table(title="laplab tracks", caption=f"* default track; user folder: {registry.user_track_dir()}")
    table.add_column("name", no_wrap=True)
    for column in ("length m", "width m"):
        table.add_column(column, justify="right")
    table.add_column("dir")
    table.add_column("waypoints", justify="right")
    table.add_column("source")
    for row in rows:
        name = row["name"] + (" *" if row["default"] else "")
        if row["error"]:
            table.add_row(name, "-", "-", "-", "-", f"{row['source']} (invalid: see --json)", style="red")
            continue
        table.add_row(name, f"{row['length_m']:.2f}", f"{row['width_m']:.3f}", row["direction"],
                      str(row["waypoints"]), row["source"])
    Console(file=sys.stdout, width=max(Console(file=sys.stdout).width, 100)).print(table)
    return 0


def show_command(args: argparse.Namespace) -> int:
    from laplab.track.plot import plot_track

    track = registry.load_track(args.name, reverse=args.reversed)
    out = args.out
    if out is None:
        stem = Path(args.name).stem if args.name.endswith(".npy") else args.name
        out = Path.cwd() / f"{stem.replace('@', '_')}{'_reversed' if args.reversed else ''}.png"
    if out.suffix.lower() != ".png":
        raise UserError(f"--out {out}: the image must be a .png file.")
    figure = plot_track(track, out, show_indices=args.indices)
    print(figure.path)
    return 0


def import_command(args: argparse.Namespace) -> int:
    path = args.file
    if not path.is_file():
        raise UserError(f"{path}: no such file; give the path of a DeepRacer route (.npy).")
    try:
        raw = np.load(path, allow_pickle=False)
    except Exception as exc:  # numpy raises several kinds for corrupt files
        raise TrackError(f"{path}: not a readable .npy array ({type(exc).__name__}: {exc}). A DeepRacer "
                         f"route is a float64 array of shape (N, 6) saved with numpy.save.") from None
    route = validate_route(raw, str(path))
    cleaned = remove_repeated_points(route)
    repeats = route.shape[0] - cleaned.shape[0]
    name = args.name or path.stem
    if repeats and not args.keep_repeated_points:
        with tempfile.TemporaryDirectory() as tmp:
            sanitized = Path(tmp) / f"{name}.npy"
            np.save(sanitized, cleaned)
            target = registry.import_track(sanitized, name=name, overwrite=args.overwrite)
        note = (f"; removed {repeats} repeated centre point(s) as current DeepRacer does "
                f"(--keep-repeated-points keeps the file's rows)")
    else:
        target = registry.import_track(path, name=name, overwrite=args.overwrite)
        note = f"; kept {repeats} repeated centre point(s)" if repeats else ""
    track = load_route_file(target, remove_repeats=False)
    print(f"imported {track.name}: {track.length:.2f} m, {track.nominal_width:.3f} m wide, {track.direction}, "
          f"{track.num_waypoints} waypoints -> {target}{note}")
    return 0


def fetch_command(args: argparse.Namespace) -> int:
    from laplab.track import fetch

    base_url = fetch.resolve_base_url(args.base_url)
    settings = fetch.FetchSettings()
    if args.names:
        from laplab.races.catalogue import route_names
        names = route_names([n.strip().removesuffix(".npy") for n in args.names.split(",") if n.strip()])
        origin = "--names"
    else:
        names = fetch.fetch_index(base_url, settings)
        origin = f"{base_url}index.json"
        if names is None:
            names, origin = fetch.shipped_route_names(), "the simapp route list shipped with laplab"
    if not names:
        raise UserError(f"no track names to fetch (from {origin}).")
    fetch.check_route_names(names)
    dest = args.dest or registry.user_track_dir()
    reserved = frozenset(registry.builtin_track_names()) if dest == registry.user_track_dir() else frozenset()
    print(f"fetching {len(names)} route(s) from {base_url} (names from {origin}) into {dest}")
    results = fetch.fetch_routes(names, base_url, dest, settings, overwrite=args.overwrite,
                                 reserved_names=reserved)
    registry._load_cached.cache_clear()  # files under already-loaded paths may have changed
    for result in results:
        stream = sys.stderr if result.status == "failed" else sys.stdout
        print(f"  {result.status:7s} {result.name}: {result.detail}", file=stream)
    counts = {status: sum(r.status == status for r in results) for status in ("fetched", "skipped", "failed")}
    print(f"fetched {counts['fetched']}, skipped {counts['skipped']}, failed {counts['failed']} "
          f"(of {len(results)}) into {dest}")
    return 1 if counts["failed"] else 0
