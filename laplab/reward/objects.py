"""DeepRacer's ``objects_*`` reward params, from a simulator's obstacles (simapp's
``TrackData.get_object_reward_params``).

For each car, its obstacles in slot order (index i of every list is object i):

- ``objects_location``: ``[x, y]`` of each object's centre, m.
- ``objects_distance``: the object's centre projected onto the centre line of the driving direction,
  as arc length from its start, m in [0, track_length) (not a distance from the car).
- ``closest_objects``: ``[previous, next]`` object indices around the car's own projection (its
  reference point's), by ``objects_distance``, wrapping round the lap.
- ``objects_left_of_center``: the object lies left of the centre line (driving direction).
- ``objects_distance_from_center``: its distance from the centre line, m.
- ``objects_heading``, ``objects_speed``: a bot car's yaw in **radians** (simapp's value; DeepRacer's
  docs say degrees) and its speed, m/s, in head-to-bot races; 0 for boxes and other models' cars, as
  simapp reports them.
- ``object_in_camera``: the next object has a floor corner or its centre inside the front camera's
  view (horizontal field of view, pitch and height of :data:`laplab.sensors.camera.FRONT_FACING_CAMERA`).

A time trial has no objects: the keys keep their defaults (``[0, 0]``, empty lists, False).
"""

from __future__ import annotations

import bisect
import math

import numpy as np

from laplab.sensors.camera import FRONT_FACING_CAMERA, CameraParams
from laplab.sim.collision import COLLISION_MARGIN
from laplab.sim.obstacles import EMPTY
from laplab.sim.race_type import HEAD_TO_BOT
from laplab.sim.simulator import Simulator
from laplab.track.projection import project_points

EMPTY_OBJECT_PARAMS = {"closest_objects": [0, 0], "objects_location": [], "objects_left_of_center": [],
                       "objects_speed": [], "objects_heading": [], "objects_distance": [],
                       "objects_distance_from_center": [], "object_in_camera": False}


def in_camera(camera: CameraParams, car_x: float, car_y: float, car_yaw: float, points: np.ndarray) -> bool:
    """Whether any ground point of ``points`` (P, 2) lies in the camera's view from the car pose."""
    c, s = math.cos(car_yaw), math.sin(car_yaw)
    cam_x = car_x + c * camera.mount_forward - s * camera.mount_lateral
    cam_y = car_y + s * camera.mount_forward + c * camera.mount_lateral
    rel = points - np.array([cam_x, cam_y])
    forward = rel[:, 0] * c + rel[:, 1] * s
    left = -rel[:, 0] * s + rel[:, 1] * c
    half_h = 0.5 * camera.fov
    half_v = math.atan(math.tan(half_h) * camera.height / camera.width)
    with np.errstate(divide="ignore", invalid="ignore"):
        across = np.abs(np.arctan2(left, forward))
        down = np.arctan2(camera.mount_up, forward)
    visible = (forward > 0) & (across <= half_h) & (np.abs(down - camera.pitch) <= half_v)
    return bool(visible.any())


def footprint(x: float, y: float, yaw: float, half_length: float, half_width: float) -> np.ndarray:
    """(5, 2): the four floor corners of a rectangle and its centre."""
    c, s = math.cos(yaw), math.sin(yaw)
    local = np.array([[1, 1], [1, -1], [-1, -1], [-1, 1]], dtype=np.float64) * [half_length, half_width]
    corners = np.stack([x + local[:, 0] * c - local[:, 1] * s, y + local[:, 0] * s + local[:, 1] * c], axis=1)
    return np.vstack([corners, [[x, y]]])


def object_params(sim: Simulator, cars: np.ndarray, camera: CameraParams = FRONT_FACING_CAMERA) -> list[dict]:
    """The ``objects_*`` params of each car of ``cars`` (K,), from ``sim.obstacles``."""
    ob, st = sim.obstacles, sim.state
    cars = np.asarray(cars, dtype=np.int64)
    if ob.slots == 0:
        return [dict(EMPTY_OBJECT_PARAMS, closest_objects=[0, 0]) for _ in cars]
    pdist = np.zeros((cars.size, ob.slots))
    lateral = np.zeros((cars.size, ob.slots))
    direction = st.direction[cars]
    for d in (0, 1):
        sel = direction == d
        if sel.any():
            pts = np.stack([ob.x[cars[sel]].ravel(), ob.y[cars[sel]].ravel()], axis=1)
            proj = project_points(sim.arrays[d], pts)
            pdist[sel] = proj.arc_length.reshape(-1, ob.slots)
            lateral[sel] = proj.lateral.reshape(-1, ob.slots)
    bots = sim.race.kind == HEAD_TO_BOT
    out = []
    for row, car in enumerate(cars.tolist()):
        slots = np.flatnonzero(ob.kind[car] != EMPTY)
        if slots.size == 0:
            out.append(dict(EMPTY_OBJECT_PARAMS, closest_objects=[0, 0]))
            continue
        dists = pdist[row, slots]
        order = np.argsort(dists, kind="stable")
        nxt = bisect.bisect_right(dists[order].tolist(), float(st.arc[car]))
        prev_i, next_i = int(order[(nxt - 1) % slots.size]), int(order[nxt % slots.size])
        k = slots[next_i]
        margin = COLLISION_MARGIN[ob.kind[car, k]]
        points = footprint(ob.x[car, k], ob.y[car, k], ob.yaw[car, k], ob.half_length[car, k] + margin,
                           ob.half_width[car, k] + margin)
        out.append({
            "closest_objects": [prev_i, next_i],
            "objects_location": [[float(ob.x[car, j]), float(ob.y[car, j])] for j in slots],
            "objects_left_of_center": (lateral[row, slots] > 0).tolist(),
            "objects_speed": (sim.field.speed[car, slots] if bots else np.zeros(slots.size)).tolist(),
            "objects_heading": (np.arctan2(np.sin(ob.yaw[car, slots]), np.cos(ob.yaw[car, slots])) if bots
                                else np.zeros(slots.size)).tolist(),
            "objects_distance": dists.tolist(),
            "objects_distance_from_center": np.abs(lateral[row, slots]).tolist(),
            "object_in_camera": in_camera(camera, st.x[car], st.y[car], st.yaw[car], points),
        })
    return out
