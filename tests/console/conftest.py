"""Fixtures of the console tests: a real server (uvicorn on 127.0.0.1, a free port) over a fresh
``$LAPLAB_HOME``, users with tokens, and tiny models made with laplab's own training calls."""

from __future__ import annotations

import shutil
import socket
from pathlib import Path
import threading
import time
from contextlib import contextmanager
from dataclasses import dataclass

import pytest

pytest.importorskip("fastapi")
pytest.importorskip("uvicorn")
httpx = pytest.importorskip("httpx")

ADMIN_TOKEN = "admin-test-token-0123456789"
CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
CHROMIUM_ARGS = ["--no-sandbox", "--disable-gpu", "--disable-background-networking", "--disable-component-update",
                 "--disable-sync", "--disable-dev-shm-usage"]
TINY_HYPERPARAMETERS = {"num_episodes_between_training": 2, "num_epochs": 3, "batch_size": 32}


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@dataclass
class RunningConsole:
    url: str
    app: object
    admin: "httpx.Client"

    def client(self, token: str | None) -> "httpx.Client":
        headers = {"Authorization": f"Bearer {token}"} if token else {}
        return httpx.Client(base_url=self.url, headers=headers, timeout=120.0)

    def add_user(self, name: str) -> "httpx.Client":
        _, token = self.app.state.store.add_user(name)
        return self.client(token)

    def wait_for(self, client, name: str, statuses: tuple[str, ...], timeout_s: float = 240.0) -> dict:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            model = client.get(f"/api/models/{name}").json()
            if model["status"] in statuses:
                return model
            time.sleep(0.2)
        raise AssertionError(f"{name} did not reach {statuses} within {timeout_s} s: {model}")


WARMUP_KERNELS = "warmup-kernels.txt"  # in a seed: the kernels' files the warm-up itself ran (one a line)
_NUMBA_SEED: dict = {}  # "root": where seeds are kept (pytest's cache folder), "cache": this session's


def pytest_configure(config):
    cache = getattr(config, "cache", None)
    if cache is not None:
        _NUMBA_SEED["root"] = cache.mkdir("laplab-numba-seed")


def _source_stamp() -> str:
    """A hash of laplab's source files (names, sizes, mtimes): a seed is remade when they change."""
    import hashlib
    from pathlib import Path

    import laplab
    digest = hashlib.sha256()
    for path in sorted(Path(laplab.__file__).parent.rglob("*.py")):
        stat = path.stat()
        digest.update(f"{path}:{stat.st_size}:{stat.st_mtime_ns}".encode())
    return digest.hexdigest()[:16]


def copy_in_tree_kernels(cache: Path) -> int:
    """Copy the kernels this session's own tests already compiled (numba's in-tree cache,
    ``laplab/**/__pycache__/*.nbi`` and ``*.nbc``) into ``cache`` in the layout numba uses under
    ``NUMBA_CACHE_DIR``, so the warm-up compiles only what is missing (about a minute of CPU on 2 cores
    otherwise). Numba checks every entry against its source file's hash and the machine, as it does its
    in-tree cache, so a stale entry is compiled again, never used. Returns how many files were copied."""
    import shutil

    from numba.core.caching import UserProvidedCacheLocator

    import laplab
    copied = 0
    for folder in Path(laplab.__file__).parent.rglob("__pycache__"):
        kernels = [*folder.glob("*.nbi"), *folder.glob("*.nbc")]
        if not kernels:
            continue
        target = cache / UserProvidedCacheLocator.get_suitable_cache_subpath(str(folder.parent / "module.py"))
        target.mkdir(parents=True, exist_ok=True)
        for path in kernels:
            shutil.copy2(path, target / path.name)
            copied += 1
    return copied


def numba_seed(base) -> Path:
    """A trusted numba cache for the consoles of the tests, made by laplab's own warm-up (as
    ``laplab serve`` makes one per home) once per source version (kept in pytest's cache folder):
    each new user's jobs start from a copy instead of compiling every kernel (tens of seconds per
    job on a loaded machine)."""
    if "cache" not in _NUMBA_SEED:
        import os
        import shutil
        import subprocess
        import sys
        from pathlib import Path

        from laplab.jobs.warmup import READY_MARKER
        root = Path(_NUMBA_SEED.get("root") or base)
        cache = root / f"numba-{_source_stamp()}"
        if not ((cache / READY_MARKER).exists() and (cache / WARMUP_KERNELS).exists()):
            for old in root.glob("numba-*"):
                shutil.rmtree(old, ignore_errors=True)
            cache.mkdir(parents=True, exist_ok=True)
            copy_in_tree_kernels(cache)
            # numba's cache log names every kernel the warm-up loads from the cache or compiles into it
            env = {**os.environ, "NUMBA_CACHE_DIR": str(cache), "NUMBA_DEBUG_CACHE": "1"}
            done = subprocess.run([sys.executable, "-m", "laplab.jobs.warmup", str(cache)], env=env, check=True,
                                  stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=900)
            assert (cache / READY_MARKER).exists()
            used = sorted({Path(line.split(" from ", 1)[-1].split(" to ", 1)[-1].strip(" '\"")).name
                           for line in done.stdout.splitlines()
                           if line.startswith(("[cache] data loaded from", "[cache] data saved to"))})
            (cache / WARMUP_KERNELS).write_text("\n".join(used) + "\n")
        _NUMBA_SEED["cache"] = cache
    return _NUMBA_SEED["cache"]


@contextmanager
def serve(home, workers: int = 2, seed_numba: bool = True, **kwargs):
    """A console over ``home`` on a free port, its numba cache seeded (:func:`numba_seed`; not with
    ``seed_numba=False``, for tests that run no job); stops it (and its jobs) on exit."""
    import shutil

    import uvicorn

    from laplab.console.app import create_app
    from laplab.jobs.warmup import trusted_cache
    from pathlib import Path
    seed = numba_seed(Path(home).parent) if seed_numba else None
    if seed is not None and not trusted_cache(Path(home)).exists():
        shutil.copytree(seed, trusted_cache(Path(home)))
    mp = pytest.MonkeyPatch()
    mp.setenv("LAPLAB_HOME", str(home))
    mp.setenv("LAPLAB_ADMIN_TOKEN", ADMIN_TOKEN)
    try:
        # warm_cache: seeded above; allow_unsandboxed: the other tests' users log in where bubblewrap is
        # missing too (test_safe_default.py tests the refusal, with allow_unsandboxed=False)
        app = create_app(workers, **{"warm_cache": False, "allow_unsandboxed": True, **kwargs})
        port = free_port()
        server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning"))
        thread = threading.Thread(target=server.run, daemon=True)
        thread.start()
        deadline = time.monotonic() + 30
        while not server.started:
            assert time.monotonic() < deadline, "the console did not start"
            time.sleep(0.05)
        url = f"http://127.0.0.1:{port}"
        admin = httpx.Client(base_url=url, headers={"Authorization": f"Bearer {ADMIN_TOKEN}"}, timeout=120.0)
        try:
            yield RunningConsole(url, app, admin)
        finally:
            admin.close()
            server.should_exit = True
            thread.join(60)
            app.state.store.close()
    finally:
        mp.undo()


@pytest.fixture(scope="session")
def serve_console():
    """The context manager :func:`serve` (for tests that need their own server settings)."""
    return serve


@pytest.fixture(scope="module")
def console(tmp_path_factory):
    with serve(tmp_path_factory.mktemp("console-home")) as running:
        yield running


@pytest.fixture(scope="session")
def numba_cache(tmp_path_factory):
    """The session's trusted numba cache (see :func:`numba_seed`)."""
    return numba_seed(tmp_path_factory.getbasetemp())


@pytest.fixture(scope="session")
def admin_token() -> str:
    return ADMIN_TOKEN


@pytest.fixture(scope="session")
def make_model():
    """``make_model(name, reward_source=None)``: see :func:`create_tiny_model`."""
    return create_tiny_model


def create_tiny_model(name: str, reward_source: str | None = None, sensor: list[str] | None = None):
    """A real model folder (initial checkpoint, no iterations) made by laplab's create_training;
    ``sensor`` (default ``["STATE"]``) e.g. ``["FRONT_FACING_CAMERA"]`` for a model the car can run."""
    from dataclasses import replace

    from laplab.env.metadata import ModelMetadata
    from laplab.train.config import TrainConfig
    from laplab.train.jobs import create_training
    config = replace(TrainConfig(), hyperparameters={**TrainConfig().hyper().to_dict(), **TINY_HYPERPARAMETERS},
                     max_time_s=5.0)
    if sensor is not None:
        config = replace(config, model_metadata={**ModelMetadata().to_dict(), "sensor": sensor})
    if reward_source is not None:
        import tempfile
        from pathlib import Path
        path = Path(tempfile.mkdtemp()) / "reward_function.py"
        path.write_text(reward_source)
        config = replace(config, reward_path=str(path))
    create_training(name, config)


@contextmanager
def signed_in_page(base_url: str, token: str, viewport: dict | None = None):
    """A page of Debian's Chromium (headless, the project's flags) signed in to the console at
    ``base_url`` with ``token``; the browser is closed on leaving. Skips without playwright or chromium."""
    playwright_api = pytest.importorskip("playwright.sync_api")
    if not shutil.which("chromium"):
        pytest.skip("chromium is not installed (apt-get install chromium)")
    with playwright_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS, headless=True, timeout=60_000)
        try:
            context = browser.new_context(**({"viewport": viewport} if viewport else {}))
            context.set_default_timeout(30_000)  # for every page of it (a test may open a second)
            page = context.new_page()
            page.goto(f"{base_url}/login")
            page.fill("#token", token)
            page.click("button[type=submit]")
            page.wait_for_url(f"{base_url}/")
            yield page
        finally:
            browser.close()
