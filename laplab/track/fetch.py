"""Downloading DeepRacer route files (``<name>.npy``) into the user's track folder.

The only network code in laplab's track package; nothing here runs unless ``laplab tracks fetch`` (or a
caller) asks for it. Each file is downloaded with :mod:`urllib`, validated as a closed DeepRacer route,
and written atomically. Files that are valid ``.npy`` arrays but not drivable closed routes (the simapp's
open ``Straight_track``) are skipped with the reason; unreachable or unreadable files count as failed.
"""

from __future__ import annotations

import io
import json
import os
import re
import tempfile
import time
import urllib.error
import urllib.parse
import urllib.request
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from laplab.track.geometry import TrackError, validate_route

DEFAULT_BASE_URL = ("https://raw.githubusercontent.com/aws-deepracer-community/deepracer-simapp/"
                    "master/bundle/routes/")
BASE_URL_ENV = "LAPLAB_TRACKS_URL"
ROUTE_NAMES_FILE = Path(__file__).resolve().parent / "route_names.txt"
_NAME_PATTERN = re.compile(r"^[A-Za-z0-9_-]+$")


@dataclass(frozen=True)
class FetchSettings:
    """How downloads behave: per-request ``timeout_s`` (s), extra attempts after a network error
    (``retries``; a 4xx answer is never retried), ``retry_delay_s`` (s) and parallel ``workers``."""

    timeout_s: float = 20.0
    retries: int = 1
    retry_delay_s: float = 1.0
    workers: int = 8


@dataclass(frozen=True)
class FetchResult:
    """Outcome for one route name: ``status`` is ``"fetched"``, ``"skipped"`` or ``"failed"``."""

    name: str
    status: str
    detail: str
    path: Path | None = None


def shipped_route_names() -> list[str]:
    """Route names of the DeepRacer simapp, as shipped with laplab (names only, no data)."""
    lines = ROUTE_NAMES_FILE.read_text(encoding="utf-8").splitlines()
    return [line.strip() for line in lines if line.strip() and not line.lstrip().startswith("#")]


def resolve_base_url(flag_value: str | None = None) -> str:
    """Base URL from the flag, else ``$LAPLAB_TRACKS_URL``, else the simapp's GitHub folder; ends in '/'."""
    url = flag_value or os.environ.get(BASE_URL_ENV) or DEFAULT_BASE_URL
    scheme = urllib.parse.urlparse(url).scheme
    if scheme not in ("http", "https", "file"):
        raise TrackError(f"track base URL {url!r} must start with http://, https:// or file:// "
                         f"(set by --base-url or ${BASE_URL_ENV}).")
    return url if url.endswith("/") else url + "/"


def check_route_names(names: list[str]) -> list[str]:
    """Reject names that are not plain file stems (letters, digits, '_' and '-'); returns them unchanged."""
    bad = [n for n in names if not _NAME_PATTERN.match(n)]
    if bad:
        raise TrackError(f"track names {bad} may hold only letters, digits, '_' and '-' "
                         f"(give names without '.npy' or folders, e.g. --names Oval_track,reInvent2019_track).")
    return names


def download(url: str, settings: FetchSettings = FetchSettings()) -> bytes:
    """Body of ``url``; retries network errors and 5xx answers ``settings.retries`` times.

    Raises ``urllib.error.HTTPError`` / ``URLError`` / ``TimeoutError`` from the last attempt.
    """
    for attempt in range(settings.retries + 1):
        try:
            with urllib.request.urlopen(url, timeout=settings.timeout_s) as response:
                return response.read()
        except urllib.error.HTTPError as exc:
            if exc.code < 500 or attempt == settings.retries:
                raise
        except (urllib.error.URLError, TimeoutError, ConnectionError):
            if attempt == settings.retries:
                raise
        time.sleep(settings.retry_delay_s)
    raise AssertionError("unreachable")


def fetch_index(base_url: str, settings: FetchSettings = FetchSettings()) -> list[str] | None:
    """Names listed by ``<base>/index.json`` (a JSON list of names, or ``{"names": [...]}``), or None
    when the server has no usable index (the simapp repository has none)."""
    try:
        payload = json.loads(download(base_url + "index.json", settings).decode("utf-8"))
    except (OSError, ValueError):  # HTTPError and URLError are OSErrors; bad JSON is a ValueError
        return None
    names = payload.get("names") if isinstance(payload, dict) else payload
    if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
        return None
    return [n[:-4] if n.endswith(".npy") else n for n in names]


def parse_route_bytes(data: bytes, source: str) -> np.ndarray:
    """The validated ``(N, 6)`` route in ``data`` (the bytes of a ``.npy`` file).

    Raises ValueError when the bytes are not a readable ``.npy`` array, TrackError when the array is not a
    valid closed DeepRacer route.
    """
    try:
        array = np.load(io.BytesIO(data), allow_pickle=False)
    except Exception as exc:  # numpy raises several kinds for corrupt data
        head = data[:40]
        raise ValueError(f"not a readable .npy array ({type(exc).__name__}: {exc}); "
                         f"{len(data)} bytes starting {head!r}") from None
    return validate_route(array, source)


def write_atomic(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` through a temporary file in the same folder, so readers never see half."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as handle:
            handle.write(data)
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def fetch_route(name: str, base_url: str, dest: Path, settings: FetchSettings = FetchSettings(),
                overwrite: bool = False, reserved_names: frozenset[str] = frozenset()) -> FetchResult:
    """Download, validate and store ``<base_url><name>.npy`` as ``dest/<name>.npy``.

    The file is stored byte for byte as served. A name in ``reserved_names`` (a built-in track that would
    shadow it) is skipped, as is an existing different file unless ``overwrite``.
    """
    url = base_url + urllib.parse.quote(name) + ".npy"
    if name in reserved_names:
        return FetchResult(name, "skipped", "a built-in track has this name and would shadow it")
    try:
        data = download(url, settings)
    except urllib.error.HTTPError as exc:
        return FetchResult(name, "failed", f"{url}: HTTP {exc.code} {exc.reason}")
    except (urllib.error.URLError, TimeoutError, ConnectionError) as exc:
        reason = getattr(exc, "reason", exc)
        return FetchResult(name, "failed", f"{url}: cannot download ({reason})")
    try:
        route = parse_route_bytes(data, url)
    except TrackError as exc:
        return FetchResult(name, "skipped", f"not a drivable route: {exc}")
    except ValueError as exc:
        return FetchResult(name, "failed", f"{url}: {exc}")
    target = dest / f"{name}.npy"
    if target.is_file():
        if target.read_bytes() == data:
            return FetchResult(name, "skipped", "already present and identical", target)
        if not overwrite:
            return FetchResult(name, "skipped", f"{target} exists with other content; --overwrite replaces it",
                               target)
    write_atomic(target, data)
    length = float(np.linalg.norm(np.diff(route[:, 0:2], axis=0), axis=1).sum())
    return FetchResult(name, "fetched", f"{route.shape[0]} waypoints, {length:.2f} m", target)


def fetch_routes(names: list[str], base_url: str, dest: Path, settings: FetchSettings = FetchSettings(),
                 overwrite: bool = False, reserved_names: frozenset[str] = frozenset()) -> list[FetchResult]:
    """:func:`fetch_route` for each name (``settings.workers`` downloads at a time), results in name order."""
    check_route_names(names)
    with ThreadPoolExecutor(max_workers=max(1, settings.workers)) as pool:
        return list(pool.map(
            lambda n: fetch_route(n, base_url, dest, settings, overwrite, reserved_names), names))
