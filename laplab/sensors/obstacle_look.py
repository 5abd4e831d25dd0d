"""What DeepRacer's obstacles look like to the sensors: sizes, material colours and their shading.

Sources (aws-deepracer-community/deepracer-simapp, commit b7599b42, the Gazebo-classic simulator the
camera looks come from; unchanged at 01f5f015):
- ``bundle/models/box_obstacle/model.sdf``: the default obstacle (``OBSTACLE_TYPE`` defaults to
  ``box_obstacle`` in ``markov/agent_ctrl/obstacles_agent_ctrl.py``): a 0.4 x 0.3 x 0.25 m box, material
  ambient = diffuse = (0.482, 0.38, 0.309) ("Brown color #7b614f"). It is spawned at z = 0.1 and falls
  onto the floor (``OBSTACLE_Z``, ``markov/agent_ctrl/constants.py``), so it stands on the ground.
- ``bundle/models/bot_car/model.sdf``: the bot car's shell ``car_body_link_v3`` with material ambient =
  diffuse = 0.156 grey ("0x28 0x28 0x28") and wheels of 0.1 grey. The shell mesh
  ``bundle/meshes/deepracer/car_body_link_v3.STL`` spans x -0.0822..0.2420, y +-0.0939, z 0.0006..0.1950 m
  in its link, which sits 0.0762 m behind and 0.0158 m above the chassis origin; the wheels reach y
  +-0.098 m. As a box: 0.324 m long, 0.196 m wide (over the wheels) and 0.16 m high: the shell's
  main top (above 0.156 m from the ground it narrows to |y| < 0.06 m, and only a hump at its front,
  |y| < 0.05 m, reaches 0.211 m). The box's centre is 0.0037 m ahead of the chassis origin, i.e.
  0.0854 m ahead of the rear axle (the chassis origin is 0.0817 m ahead of it, ``docs/car.md``).
- Other models' cars (head-to-head): the racecar URDF's same shell, coloured by
  ``markov/gazebo_utils/model_updater.py`` ``update_color``: ambient = 0.1 x colour, diffuse = 0.35 x
  colour, with the colour from ``markov/rollout_constants.py`` ``COLOR_MAP`` (the car's ``CAR_COLOR``,
  "Black" (0.1, 0.1, 0.1) when the race's yaml names none).
- Every world's ``<scene><ambient>`` is 0.5 0.5 0.5 (``bundle/worlds/*.world``).

Shading is Gazebo's fixed diffuse model: ``scene_ambient * ambient + sum over lights of diffuse *
max(0, n . l) * attenuation``, per face of the box (four sides and the top) at the face's centre,
with the track look's lights (:mod:`laplab.sensors.walls`; a default sun for looks without lights).
Specular light and shadows are not modelled; a face is one flat colour.

The kind codes match ``laplab.sim.obstacles`` (EMPTY, BOX, BOT_CAR, MODEL_CAR = 0, 1, 2, 3), which
this layer cannot import; tests/sensors/test_obstacles.py checks that they agree.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from numba import njit

from laplab.sensors.walls import Light

EMPTY, BOX, BOT_CAR, MODEL_CAR = 0, 1, 2, 3
NUM_KINDS = 4
BOX_SIZE = (0.40, 0.30, 0.25)          # m: length, width, height of simapp's box_obstacle
CAR_SIZE = (0.324, 0.196, 0.16)        # m: length, width, height of a DeepRacer car's body box
CAR_BODY_AHEAD = 0.0854                # m: the body box's centre ahead of the car's rear axle
SCENE_AMBIENT = 0.5                    # every DeepRacer world's <scene><ambient>
# rollout_constants.COLOR_MAP: the CAR_COLOR names of a race yaml -> RGB in 0..1.
CAR_COLORS: dict[str, tuple[float, float, float]] = {
    "Black": (0.1, 0.1, 0.1), "Grey": (0.529, 0.584, 0.588), "Blue": (0.266, 0.372, 0.898),
    "Red": (0.878, 0.101, 0.145), "Orange": (1.0, 0.627, 0.039), "White": (1.0, 1.0, 1.0),
    "Purple": (0.611, 0.164, 0.764),
}
DEFAULT_SUN = Light("directional", (0.8, 0.8, 0.8), (-0.5, 0.1, -0.9))  # Gazebo's model://sun
# Faces of an obstacle's box, in the kernels' order: front (+length), back, left (+width), right, top.
FRONT, BACK, LEFT, RIGHT, TOP = range(5)
NUM_FACES = 5


@dataclass(frozen=True)
class ObstacleLook:
    """Material colours (RGB in 0..1, Gazebo ``ambient`` and ``diffuse``) of each obstacle kind.

    ``model_car_color`` names another model's car colour (a ``CAR_COLORS`` key, DeepRacer's
    ``CAR_COLOR``); its material is 0.1 x (ambient) and 0.35 x (diffuse) that colour, as simapp sets it.
    """

    box_diffuse: tuple[float, float, float] = (0.482, 0.38, 0.309)
    box_ambient: tuple[float, float, float] = (0.482, 0.38, 0.309)
    bot_car_diffuse: tuple[float, float, float] = (0.156, 0.156, 0.156)
    bot_car_ambient: tuple[float, float, float] = (0.156, 0.156, 0.156)
    model_car_color: str = "Black"
    scene_ambient: float = SCENE_AMBIENT

    def __post_init__(self) -> None:
        if self.model_car_color not in CAR_COLORS:
            raise ValueError(f"ObstacleLook.model_car_color must be one of {', '.join(CAR_COLORS)} (DeepRacer's "
                             f"CAR_COLOR), got {self.model_car_color!r}")
        for name in ("box_diffuse", "box_ambient", "bot_car_diffuse", "bot_car_ambient"):
            value = getattr(self, name)
            if len(value) != 3 or not all(0.0 <= v <= 1.0 for v in value):
                raise ValueError(f"ObstacleLook.{name} must be three numbers in 0..1 (RGB), got {value!r}")
        if not 0.0 <= self.scene_ambient <= 1.0:
            raise ValueError(f"ObstacleLook.scene_ambient must be in 0..1, got {self.scene_ambient!r}")

    def materials(self) -> tuple[np.ndarray, np.ndarray]:
        """(diffuse, ambient), each (NUM_KINDS, 3) float64 in 0..1, indexed by kind code (EMPTY: zeros)."""
        colour = np.array(CAR_COLORS[self.model_car_color])
        diffuse = np.array([(0.0, 0.0, 0.0), self.box_diffuse, self.bot_car_diffuse, 0.35 * colour])
        ambient = np.array([(0.0, 0.0, 0.0), self.box_ambient, self.bot_car_ambient, 0.1 * colour])
        return diffuse, ambient


DEFAULT_OBSTACLE_LOOK = ObstacleLook()


class ObstacleBoxes:
    """Checked obstacle arrays for the sensor kernels: ``boxes`` (N, K, 6) float64 [x, y, yaw,
    half_length, half_width, height] (m, rad) and ``kind`` (N, K) int64."""

    __slots__ = ("boxes", "kind")

    def __init__(self, boxes: np.ndarray, kind: np.ndarray):
        self.boxes, self.kind = boxes, kind

    @property
    def any(self) -> bool:
        return bool(self.kind.size and (self.kind != EMPTY).any())


def obstacle_boxes(obstacles, num_cars: int, caller: str) -> ObstacleBoxes | None:
    """Check and pack ``obstacles``: seven (N, K) arrays in the order x, y, yaw, half_length,
    half_width, height, kind (a ``laplab.sim.obstacles.Obstacles`` is such a tuple); None when it is
    None or every slot is empty. Raises ValueError naming ``caller`` on bad shapes or values."""
    if obstacles is None:
        return None
    fields = tuple(obstacles)
    if len(fields) != 7:
        raise ValueError(f"{caller}: obstacles must be seven (N, K) arrays (x, y, yaw, half_length, half_width, "
                         f"height, kind), got {len(fields)}")
    kind = np.asarray(fields[6])
    boxes = np.stack([np.asarray(f, dtype=np.float64) for f in fields[:6]], axis=-1)
    if kind.ndim != 2 or kind.shape[0] != num_cars or boxes.shape != kind.shape + (6,):
        raise ValueError(f"{caller}: obstacles must be (N, K) arrays with N = {num_cars} cars (one row per pose), "
                         f"got shapes {[np.shape(f) for f in fields]}")
    kind = np.ascontiguousarray(kind, dtype=np.int64)
    used = kind != EMPTY
    if not used.any():
        return None
    if (kind < 0).any() or (kind >= NUM_KINDS).any():
        raise ValueError(f"{caller}: obstacle kind codes must be 0..{NUM_KINDS - 1} (empty, box, bot car, model "
                         f"car), got {np.unique(kind).tolist()}")
    solid = boxes[used]
    if not np.isfinite(solid).all() or (solid[:, 3:] <= 0).any():
        raise ValueError(f"{caller}: every non-empty obstacle needs finite x, y, yaw and positive half_length, "
                         "half_width and height (m)")
    return ObstacleBoxes(np.ascontiguousarray(boxes), kind)


@lru_cache(maxsize=32)
def light_table(lights: tuple[Light, ...]) -> np.ndarray:
    """(L, 13) float64 rows [is_point, diffuse rgb, unit vector towards a directional light, position,
    attenuation (constant, linear, quadratic)] of ``lights`` (none: Gazebo's default sun); read-only."""
    rows = []
    for light in lights or (DEFAULT_SUN,):
        towards = -np.asarray(light.direction, dtype=np.float64)
        towards = towards / (np.linalg.norm(towards) or 1.0)
        rows.append([float(light.kind != "directional"), *light.diffuse, *towards, *light.position,
                     *light.attenuation])
    table = np.array(rows, dtype=np.float64)
    table.flags.writeable = False
    return table


@njit(cache=True)
def _face_colours_kernel(boxes, kind, diffuse, ambient, scene_ambient, lights, out):
    """out (N, K, 5, 4) uint8: the lit RGB and grey of every face (see :func:`face_colours`)."""
    weights = (299, 587, 114)
    for n in range(kind.shape[0]):
        for q in range(kind.shape[1]):
            x, y, yaw = boxes[n, q, 0], boxes[n, q, 1], boxes[n, q, 2]
            half_length, half_width, height = boxes[n, q, 3], boxes[n, q, 4], boxes[n, q, 5]
            c, s = np.cos(yaw), np.sin(yaw)
            k = kind[n, q]
            for face in range(NUM_FACES):
                nx, ny, nz, pz = 0.0, 0.0, 1.0, height  # TOP
                if face == FRONT or face == BACK:
                    sign = 1.0 if face == FRONT else -1.0
                    nx, ny, nz, pz = sign * c, sign * s, 0.0, 0.5 * height
                elif face == LEFT or face == RIGHT:
                    sign = 1.0 if face == LEFT else -1.0
                    nx, ny, nz, pz = -sign * s, sign * c, 0.0, 0.5 * height
                reach = half_length if face <= BACK else (half_width if face <= RIGHT else 0.0)
                px, py = x + reach * nx, y + reach * ny
                grey = 500
                for channel in range(3):
                    gain = 0.0
                    for i in range(lights.shape[0]):
                        if lights[i, 0] == 0.0:
                            cosine, scale = max(nx * lights[i, 4] + ny * lights[i, 5] + nz * lights[i, 6], 0.0), 1.0
                        else:
                            ox, oy, oz = lights[i, 7] - px, lights[i, 8] - py, lights[i, 9] - pz
                            distance = max(np.sqrt(ox * ox + oy * oy + oz * oz), 1e-9)
                            cosine = max((nx * ox + ny * oy + nz * oz) / distance, 0.0)
                            scale = 1.0 / max(lights[i, 10] + lights[i, 11] * distance
                                              + lights[i, 12] * distance * distance, 1e-9)
                        gain += cosine * scale * lights[i, 1 + channel]
                    rgb = scene_ambient * ambient[k, channel] + diffuse[k, channel] * gain
                    value = min(max(np.rint(255.0 * min(rgb, 1.0)), 0.0), 255.0)
                    out[n, q, face, channel] = np.uint8(value)
                    grey += weights[channel] * np.int64(value)
                out[n, q, face, 3] = np.uint8(grey // 1000)


def face_colours(packed: ObstacleBoxes, lights: tuple[Light, ...] = (),
                 look: ObstacleLook = DEFAULT_OBSTACLE_LOOK) -> np.ndarray:
    """(N, K, NUM_FACES, 4) uint8 colour of every face of every obstacle: R, G, B and ITU-R 601 grey
    (:func:`laplab.sensors.texture.luma601`).

    A face shows ``scene_ambient * ambient + diffuse * sum over lights of light_diffuse * max(0, n . l)
    * attenuation`` (0..1, times 255, rounded), lit at its centre with its outward normal; ``lights``:
    a track look's ``TextureParams.wall_lights`` (none: Gazebo's default sun).
    """
    diffuse, ambient = look.materials()
    out = np.empty(packed.kind.shape + (NUM_FACES, 4), dtype=np.uint8)
    _face_colours_kernel(packed.boxes, packed.kind, diffuse, ambient, float(look.scene_ambient),
                         light_table(tuple(lights)), out)
    return out
