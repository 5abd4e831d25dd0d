"""Pictures of an env's cars for Gymnasium's ``render_mode="rgb_array"`` (video recorders, notebooks).

Two views, picked by the env's ``render_view``:

- ``"topdown"`` (default): the whole track from above with every car and its camera's field of view,
  (H, 800, 3) uint8 (:func:`laplab.sensors.render.draw_topdown`).
- ``"camera"``: what the front camera of car ``render_car`` sees, in colour for people
  (480, 640, 3) uint8 (:data:`laplab.sensors.camera.HUMAN_CAMERA`), not the model's grey input.
"""

from __future__ import annotations

import numpy as np

from laplab.sim.simulator import Simulator

RENDER_MODES = ["rgb_array"]
RENDER_VIEWS = ("topdown", "camera")
RENDER_FPS = 15  # DeepRacer's decision rate: one frame per step


def check_render_options(render_mode: str | None, render_view: str) -> None:
    if render_mode is not None and render_mode not in RENDER_MODES:
        raise ValueError(f"render_mode must be one of {RENDER_MODES} or None, got {render_mode!r}")
    if render_view not in RENDER_VIEWS:
        raise ValueError(f"render_view must be one of {RENDER_VIEWS}, got {render_view!r}")


class FrameRenderer:
    """Draws the cars of one :class:`Simulator` (the track texture is built on the first camera frame)."""

    def __init__(self, sim: Simulator, view: str = "topdown", car: int = 0):
        check_render_options(None, view)
        if not 0 <= car < sim.num_cars:
            raise ValueError(f"render_car must be a car index 0..{sim.num_cars - 1}, got {car}")
        self.sim, self.view, self.car = sim, view, car
        self._texture = None

    def frame(self) -> np.ndarray:
        """(H, W, 3) uint8 RGB picture of the current state."""
        poses = self.sim.poses()
        if self.view == "topdown":
            from laplab.sensors.render import draw_topdown
            obstacles = self.sim.obstacles if self.sim.obstacles.slots else None
            return draw_topdown(self.sim.track, poses, obstacles=obstacles)
        from laplab.sensors.camera import HUMAN_CAMERA, render_camera
        if self._texture is None:
            from laplab.sensors.look import texture_for_track
            self._texture = texture_for_track(self.sim.track)
        from laplab.env.observations import obstacle_rows
        car = np.array([self.car])
        return render_camera(self._texture, poses[car], HUMAN_CAMERA, obstacles=obstacle_rows(self.sim, car))[0]
