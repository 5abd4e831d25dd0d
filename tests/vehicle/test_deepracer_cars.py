"""DeepRacer's cars: closed-form responses (delay, lags, speed ratio, steady circles), numba/numpy parity,
the version -> car mapping, and each car against a slice of DeepRacer's own logs (skipped without them)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from laplab.analysis.fidelity import build_windows, find_simtraces, score
from laplab.vehicle.dynamics import CarState, step, step_reference
from laplab.vehicle.params import CLASSIC, DEEPRACER, DEEPRACER_V4, DEEPRACER_V5, DEEPRACER_V6, VehicleParams
from laplab.vehicle.physics import PhysicsError, car_for_version, resolve_physics, version_for_car

CARS = [DEEPRACER_V4, DEEPRACER_V5, DEEPRACER_V6]
REAL = Path(__file__).resolve().parents[3] / "shared" / "real-deepracer"


def state_of(n=1, x=0.0, y=0.0, yaw=0.0, speed=0.0, steer=0.0) -> CarState:
    return CarState(*(np.full(n, float(v)) for v in (x, y, yaw, speed, steer)))


# ---------------------------------------------------------------- closed form


def test_action_delay_holds_the_previous_command_for_its_share_of_the_step():
    """No lags, instant speed: of the step's 4 sub-steps two run at the old speed (1 m/s), the third
    changes speed (the trapezoid's 2 m/s) and the last runs at the new (3 m/s)."""
    car = CLASSIC.with_(action_delay=0.5, max_acceleration=1e6, max_braking=1e6)
    after = step(state_of(speed=1.0), np.zeros(1), np.full(1, 3.0), car, previous=(np.zeros(1), np.full(1, 1.0)))
    assert after.x[0] == pytest.approx(car.dt / 4 * (1.0 + 1.0 + 2.0 + 3.0), rel=1e-9)
    held = step(state_of(speed=1.0), np.zeros(1), np.full(1, 3.0), car)  # the same command held: no delay
    assert held.x[0] == pytest.approx(car.dt / 4 * (2.0 + 3.0 + 3.0 + 3.0), rel=1e-9)


def test_steering_follows_a_first_order_lag():
    tau = 0.3
    car = CLASSIC.with_(steering_time_constant=tau, steering_rate_deg=1e6)
    state = state_of(speed=1.0)
    for k in range(1, 6):
        state = step(state, np.full(1, 0.4), np.full(1, 1.0), car)
        assert state.steer[0] == pytest.approx(0.4 * (1.0 - math.exp(-k * car.dt / tau)), rel=1e-9)


def test_speed_settles_at_the_speed_ratio_times_the_command():
    car = CLASSIC.with_(speed_ratio=1.03, speed_time_constant=0.1)
    state = state_of()
    for _ in range(60):
        state = step(state, np.zeros(1), np.full(1, 2.0), car)
    assert state.speed[0] == pytest.approx(2.06, rel=1e-6)


@pytest.mark.parametrize("car", CARS, ids=lambda c: c.name)
@pytest.mark.parametrize("steer_deg, speed", [(10.0, 1.0), (-20.0, 1.5), (30.0, 0.8)])
def test_a_held_command_drives_the_circle_of_the_cars_curvature(car, steer_deg, speed):
    """Once delay and lags have settled, the pivot runs on a circle of radius 1 / curvature(steer, speed)."""
    steer = math.radians(steer_deg)
    state = state_of(speed=speed * car.speed_ratio)
    for _ in range(60):
        state = step(state, np.full(1, steer), np.full(1, speed), car)
    pivots = []
    for _ in range(90):
        state = step(state, np.full(1, steer), np.full(1, speed), car)
        pivots.append([state.x[0] + car.pivot_offset * math.cos(state.yaw[0]),
                       state.y[0] + car.pivot_offset * math.sin(state.yaw[0])])
    xy = np.array(pivots)
    a = np.column_stack([2.0 * xy, np.ones(len(xy))])
    (cx, cy, c), *_ = np.linalg.lstsq(a, (xy * xy).sum(axis=1), rcond=None)
    radius = math.sqrt(c + cx * cx + cy * cy)
    expected = 1.0 / abs(float(car.curvature(steer, speed * car.speed_ratio)))
    assert radius == pytest.approx(expected, rel=0.01)


@pytest.mark.parametrize("car", CARS, ids=lambda c: c.name)
def test_steering_for_curvature_inverts_the_curvature(car):
    kappa = np.array([-1.2, -0.4, 0.0, 0.3, 1.0])
    speed = np.array([0.8, 1.5, 2.0, 1.0, 0.6])
    steer = car.steering_for_curvature(kappa, speed)
    np.testing.assert_allclose(car.curvature(steer, speed), kappa, atol=1e-9)


@pytest.mark.parametrize("car", [*CARS, CLASSIC], ids=lambda c: c.name)
@pytest.mark.parametrize("count", [37, 600])  # serial and parallel loops
def test_numba_step_matches_numpy_reference(car, count):
    rng = np.random.default_rng(count)
    state = CarState(rng.uniform(-10, 10, count), rng.uniform(-10, 10, count), rng.uniform(-math.pi, math.pi, count),
                     rng.uniform(0, 4, count), rng.uniform(-0.5, 0.5, count))
    previous = (rng.uniform(-0.6, 0.6, count), rng.uniform(0, 4, count))
    for _ in range(3):
        cmd = (rng.uniform(-0.8, 0.8, count), rng.uniform(-0.5, 4.5, count))
        fast = step(state, *cmd, car, previous=previous)
        ref = step_reference(state, *cmd, car, previous=previous)
        for name, a, b in zip(CarState._fields, fast, ref):
            np.testing.assert_allclose(a, b, rtol=0, atol=1e-9, err_msg=f"{car.name} {name}")
        state, previous = fast, cmd


# ---------------------------------------------------------------- versions


@pytest.mark.parametrize("version, car", [("1", "deepracer-v4"), ("3.0", "deepracer-v4"), ("4", "deepracer-v4"),
                                          ("5", "deepracer-v5"), ("5.0", "deepracer-v5"), ("6", "deepracer-v6"),
                                          ("6.0", "deepracer-v6"), (None, "deepracer-v6"), ("", "deepracer-v6")])
def test_model_metadata_version_chooses_the_car_as_simapp_does(version, car):
    assert car_for_version(version) == car


def test_physics_choices_and_their_errors():
    assert resolve_physics("4") == "deepracer-v4" and resolve_physics("classic") == "laplab-classic"
    assert resolve_physics("deepracer-v5") == "deepracer-v5" and resolve_physics(" 6 ") == "deepracer-v6"
    with pytest.raises(PhysicsError, match="--physics 'seven': write 4, 5 or 6"):
        resolve_physics("seven")
    with pytest.raises(PhysicsError, match="not a number"):
        car_for_version("five")
    assert version_for_car("deepracer-v4", "6") == "4" and version_for_car("deepracer-v4", "3") == "3"
    assert version_for_car("laplab-classic", "5") == "5"
    assert DEEPRACER is DEEPRACER_V6


def test_metadata_without_a_version_gets_deepracer_on_aws_car():
    from laplab.env.metadata import MetadataError, metadata_from_dict
    from laplab.train.config import TrainConfig
    metadata = metadata_from_dict({"action_space": {"steering_angle": {"low": -30, "high": 30},
                                                    "speed": {"low": 0.5, "high": 2}},
                                   "action_space_type": "continuous"}, "m.json")
    assert TrainConfig(model_metadata=metadata).car == "deepracer-v6"
    assert TrainConfig(model_metadata={"version": "4"}).car == "deepracer-v4"
    # the metadata a job is given chooses the car, also through replace() of laplab's defaults
    from dataclasses import replace
    assert replace(TrainConfig(), model_metadata={"version": "5"}).car == "deepracer-v5"
    with pytest.raises(MetadataError, match="m.json: model_metadata.json \"version\" 'x' is not a number"):
        metadata_from_dict({"version": "x"}, "m.json")


def test_physics_override_sets_the_metadata_version_and_old_folders_keep_the_classic_car():
    from laplab.train.config import CONFIG_VERSION, TrainConfig
    config = TrainConfig(vehicle="deepracer-v4")
    assert config.model_metadata.version == "4"
    old = {**TrainConfig().to_dict(), "version": 1, "vehicle": "deepracer"}
    assert TrainConfig.from_dict(old).car == "laplab-classic"
    again = TrainConfig.from_dict(TrainConfig.from_dict(old).to_dict())
    assert again.car == "laplab-classic" and again.version == CONFIG_VERSION


# ---------------------------------------------------------------- against DeepRacer's logs

LOGS = [("console-2022-reinvent_base", DEEPRACER_V4), ("drfc-2022-reinvent_base", DEEPRACER_V4),
        ("console-2023-reInvent2019_wide_ccw", DEEPRACER_V5), ("droa-2026-reInvent2019_wide_cw", DEEPRACER_V6)]


@pytest.mark.parametrize("folder, car", LOGS, ids=[f for f, _ in LOGS])
def test_each_car_replays_a_slice_of_its_simulators_logs(folder, car: VehicleParams):
    """Median position error after 1 s on a slice of the log: the car's own within 12 cm, laplab's
    classic car (51, 51, 16 and 36 cm on the whole logs) beyond 14 cm."""
    if not (REAL / folder).is_dir():
        pytest.skip(f"{REAL / folder} not present")
    paths = find_simtraces(REAL / folder)[:4]
    windows = build_windows(paths, stride=3)
    assert windows.size > 500
    own, classic = score(car, windows), score(CLASSIC, windows)
    assert np.median(own.position_error) < 0.12, own.summary()
    assert np.median(classic.position_error) > 0.14, classic.summary()
