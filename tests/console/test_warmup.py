"""The server's trusted warm-up (laplab.jobs.warmup) compiles what a new user's first jobs run,
camera models' kernels included, so that a seeded user's first camera job starts without compiling."""

from __future__ import annotations

from laplab.jobs.warmup import READY_MARKER
from tests.console.conftest import WARMUP_KERNELS


def test_the_warmup_cache_holds_the_simulator_and_the_camera_kernels(numba_cache):
    assert (numba_cache / READY_MARKER).exists()
    # the kernels the warm-up ran (compiled, or loaded where the session's tests had compiled them:
    # tests/console/conftest.py's seed), each found in the cache
    used = (numba_cache / WARMUP_KERNELS).read_text().split()
    assert all(any(numba_cache.rglob(name)) for name in used)
    names = {name.split("-")[0] for name in used}
    assert "camera_kernel.render_kernel" in names  # the front camera's renderer
    assert any(name.startswith("texture.") for name in names)  # the track's camera texture
    # the simulator's step and observation, the track's projection and the reward's params kernels too
    assert {"kernel._step_range", "kernel.observe_kernel", "projection._project_loop",
            "params_geometry._reward_geometry_loop", "dynamics._lag_factor"} <= names, sorted(names)
