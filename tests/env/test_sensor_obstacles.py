"""The observation builder hands each car's own obstacles (``Simulator.obstacles``, when the simulator
has them) to the camera and the lidar; a simulator without them observes as before."""

import numpy as np

from laplab.env.metadata import metadata_from_dict
from laplab.env.observations import ObservationBuilder, obstacle_rows
from laplab.env.spec import model_spec
from laplab.sim.obstacles import BOX, Obstacles, no_obstacles
from laplab.sim.simulator import Simulator
from laplab.track.registry import load_track


def box_ahead_of(poses, car, slots=2, distance=1.0):
    """Obstacles with one 0.4 x 0.3 x 0.25 m box ``distance`` m ahead of car ``car`` only."""
    obstacles = no_obstacles(len(poses), slots)
    x, y, yaw = poses[car]
    for field, value in (("x", x + distance * np.cos(yaw)), ("y", y + distance * np.sin(yaw)), ("yaw", yaw),
                         ("half_length", 0.2), ("half_width", 0.15), ("height", 0.25)):
        getattr(obstacles, field)[car, 0] = value
    obstacles.kind[car, 0] = BOX
    return obstacles


class SimulatorWithObstacles(Simulator):
    """A Simulator whose ``obstacles`` the test sets (shadowing whatever the base class defines)."""

    obstacles = None


def test_camera_and_lidar_observations_see_the_simulators_obstacles_per_car():
    sim = SimulatorWithObstacles(load_track("oval"), num_cars=3)
    sim.reset()
    spec = model_spec(metadata_from_dict({"sensor": ["FRONT_FACING_CAMERA", "LIDAR"]}))
    sim.obstacles = no_obstacles(3)  # a time trial: K = 0
    before = ObservationBuilder(sim, spec, sensor_noise=False).observe()
    assert obstacle_rows(sim, np.arange(3)) is None
    sim.obstacles = None
    assert obstacle_rows(sim, np.arange(3)) is None
    obstacles = box_ahead_of(sim.poses(), car=1)
    sim.obstacles = lambda: obstacles  # what the race-type simulator provides (a method or an attribute)
    rows = obstacle_rows(sim, np.array([2, 1]))
    assert isinstance(rows, tuple) and rows[6].tolist() == [[0, 0], [BOX, 0]]
    after = ObservationBuilder(sim, spec, sensor_noise=False).observe()
    camera, lidar = "FRONT_FACING_CAMERA", "LIDAR"
    for car in (0, 2):
        assert np.array_equal(after[camera][car], before[camera][car])
        assert np.array_equal(after[lidar][car], before[lidar][car])
    assert np.mean(after[camera][1] != before[camera][1]) > 0.05
    # LIDAR observations clip at 1 m; the box's face 0.7 m ahead of the lidar shows in the forward beams.
    assert after[lidar][1].min() < 0.75 and np.all(after[lidar][1] <= before[lidar][1])
    sim.obstacles = Obstacles(*obstacles)
    again = ObservationBuilder(sim, spec, sensor_noise=False).observe()
    assert np.array_equal(again[camera], after[camera])
