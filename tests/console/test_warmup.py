"""The server's trusted warm-up (laplab.jobs.warmup) compiles what a new user's first jobs run,
camera models' kernels included, so that a seeded user's first camera job starts without compiling."""

from __future__ import annotations

from laplab.jobs.warmup import READY_MARKER


def test_the_warmup_cache_holds_the_simulator_and_the_camera_kernels(numba_cache):
    assert (numba_cache / READY_MARKER).exists()
    names = {path.name.split("-")[0] for path in numba_cache.rglob("*.nbi")}
    assert "camera_kernel.render_kernel" in names  # the front camera's renderer
    assert any(name.startswith("texture.") for name in names)  # the track's camera texture
    assert len(names) >= 20, sorted(names)  # the simulator's step, sensors and track kernels too
