"""Dynamics of laplab's classic car (the kinematic bicycle with no lags, which every preset builds on):
closed-form circles, speed and steering limits, numba/numpy parity. DeepRacer's cars: test_deepracer_cars.py."""

from __future__ import annotations

import math

import numpy as np
import pytest

from laplab.vehicle.dynamics import (
    CarState, body_corners, reference_point, step, step_reference, wheel_centers,
)
from laplab.vehicle.params import CLASSIC as DEEPRACER, VehicleParams, vehicle_preset


def state_of(n: int = 1, x=0.0, y=0.0, yaw=0.0, speed=0.0, steer=0.0) -> CarState:
    return CarState(*(np.full(n, float(v)) for v in (x, y, yaw, speed, steer)))


def drive(state: CarState, cmd_steer: float, cmd_speed: float, steps: int,
          params: VehicleParams = DEEPRACER) -> list[CarState]:
    """States after each of ``steps`` decisions at a constant command."""
    n = state.x.shape[0]
    out = []
    for _ in range(steps):
        state = step(state, np.full(n, cmd_steer), np.full(n, cmd_speed), params)
        out.append(state)
    return out


def fit_circle(xy: np.ndarray) -> tuple[float, np.ndarray, float]:
    """Least-squares (Kasa) circle through points (M, 2): (radius, centre (2,), rms residual)."""
    a = np.column_stack([2.0 * xy, np.ones(len(xy))])
    b = (xy * xy).sum(axis=1)
    (cx, cy, c), *_ = np.linalg.lstsq(a, b, rcond=None)
    radius = math.sqrt(c + cx * cx + cy * cy)
    residual = float(np.sqrt(np.mean((np.hypot(xy[:, 0] - cx, xy[:, 1] - cy) - radius) ** 2)))
    return radius, np.array([cx, cy]), residual


def rear_axle_path(states: list[CarState]) -> np.ndarray:
    return np.array([[s.x[0], s.y[0]] for s in states])


# ---------------------------------------------------------------- closed form


@pytest.mark.parametrize("speed, steer", [(0.5, 0.3), (0.3, math.radians(30)), (1.0, math.radians(10)),
                                          (0.8, math.radians(-20))])
def test_constant_steering_at_low_speed_drives_the_kinematic_circle(speed, steer):
    """Below the grip limit the rear axle follows a circle of radius wheelbase / tan(steer)."""
    params = DEEPRACER
    radius_expected = params.wheelbase / math.tan(abs(steer))
    assert speed ** 2 / radius_expected < params.max_lateral_acceleration  # really below the grip limit
    states = drive(state_of(speed=speed, steer=steer), steer, speed, 150)
    radius, centre, residual = fit_circle(rear_axle_path(states))
    assert radius == pytest.approx(radius_expected, rel=0.02)
    assert residual < 0.01 * radius_expected
    # turning left (steer > 0) puts the centre on the car's left: +y from a start at the origin facing +x
    assert np.sign(centre[1]) == np.sign(steer)
    assert abs(centre[0]) < 0.02 * radius_expected


def test_grip_limit_caps_lateral_acceleration_and_the_car_understeers():
    """At 3 m/s on full lock the car cannot turn on the 0.29 m kinematic circle: it runs wide on v^2 / a_lat."""
    params = DEEPRACER
    speed, steer = 3.0, params.max_steering
    kinematic = params.wheelbase / math.tan(steer)
    states = drive(state_of(speed=speed, steer=steer), steer, speed, 120)
    radius, _, residual = fit_circle(rear_axle_path(states))
    assert radius == pytest.approx(speed ** 2 / params.max_lateral_acceleration, rel=0.02)
    assert radius > 5 * kinematic
    yaw = np.unwrap([s.yaw[0] for s in states])
    yaw_rate = np.diff(yaw) / params.dt
    lateral_acceleration = speed * np.abs(yaw_rate)
    assert lateral_acceleration.max() <= params.max_lateral_acceleration * (1 + 1e-9)
    assert lateral_acceleration.min() >= params.max_lateral_acceleration * (1 - 1e-6)  # saturated all along


def test_grip_limit_scales_with_its_parameter():
    params = DEEPRACER.with_(max_lateral_acceleration=2.0)
    states = drive(state_of(speed=2.0, steer=params.max_steering), params.max_steering, 2.0, 150, params)
    radius, _, _ = fit_circle(rear_axle_path(states))
    assert radius == pytest.approx(2.0 ** 2 / 2.0, rel=0.02)


def test_speed_rises_at_the_acceleration_limit_and_falls_at_the_braking_limit():
    params = DEEPRACER
    rising = drive(state_of(), 0.0, params.max_speed, 20)
    speeds = np.array([s.speed[0] for s in rising])
    expected = np.minimum(params.max_acceleration * params.dt * np.arange(1, 21), params.max_speed)
    np.testing.assert_allclose(speeds, expected, atol=1e-12)
    # distance covered under constant acceleration: a t^2 / 2 (exact for the trapezoid rule)
    t = 10 * params.dt
    assert rising[9].x[0] == pytest.approx(0.5 * params.max_acceleration * t * t, rel=1e-9)

    falling = drive(state_of(speed=params.max_speed), 0.0, params.min_speed, 20)
    speeds = np.array([s.speed[0] for s in falling])
    expected = np.maximum(params.max_speed - params.max_braking * params.dt * np.arange(1, 21), params.min_speed)
    np.testing.assert_allclose(speeds, expected, atol=1e-12)
    assert params.max_braking != params.max_acceleration  # the two limits are told apart above


def test_speed_holds_and_never_goes_negative():
    holding = drive(state_of(speed=2.0), 0.0, 2.0, 5)
    assert all(s.speed[0] == 2.0 for s in holding)
    assert holding[-1].x[0] == pytest.approx(2.0 * 5 * DEEPRACER.dt, rel=1e-12)
    stopping = drive(state_of(speed=1.0), 0.0, -3.0, 10)  # a negative command means stop, not reverse
    assert min(s.speed[0] for s in stopping) >= 0.0
    assert stopping[-1].speed[0] == 0.0
    x_stop = stopping[-1].x[0]
    assert x_stop > 0 and drive(stopping[-1], 0.0, 0.0, 3)[-1].x[0] == x_stop


def test_steering_slew_rate_and_limit():
    params = DEEPRACER
    per_step = params.steering_rate * params.dt  # 24 degrees per 1/15 s decision
    states = drive(state_of(), math.radians(90), 1.0, 3)  # beyond the limit: clipped to 30 degrees
    steer = [s.steer[0] for s in states]
    assert steer[0] == pytest.approx(per_step, abs=1e-12)
    assert steer[1] == pytest.approx(params.max_steering, abs=1e-12)
    assert steer[2] == pytest.approx(params.max_steering, abs=1e-12)
    # from full left to full right: two decisions of 24 degrees, then 12
    back = drive(state_of(steer=params.max_steering), -params.max_steering, 1.0, 3)
    np.testing.assert_allclose([s.steer[0] for s in back],
                               [params.max_steering - per_step, params.max_steering - 2 * per_step,
                                -params.max_steering], atol=1e-12)
    slow = params.with_(steering_rate_deg=60.0)
    one = drive(state_of(), params.max_steering, 1.0, 1, slow)[0]
    assert one.steer[0] == pytest.approx(math.radians(60.0) * slow.dt, abs=1e-12)


def test_straight_driving_and_yaw_wrap():
    states = drive(state_of(x=1.0, y=2.0, yaw=math.radians(135), speed=1.5), 0.0, 1.5, 6)
    travelled = 1.5 * 6 * DEEPRACER.dt
    assert states[-1].x[0] == pytest.approx(1.0 + travelled * math.cos(math.radians(135)), abs=1e-12)
    assert states[-1].y[0] == pytest.approx(2.0 + travelled * math.sin(math.radians(135)), abs=1e-12)
    circling = drive(state_of(speed=0.5, steer=0.4), 0.4, 0.5, 200)
    yaws = np.array([s.yaw[0] for s in circling])
    assert (yaws > -math.pi).all() and (yaws <= math.pi).all()
    assert np.ptp(yaws) > 6.0  # it went all the way round


# ---------------------------------------------------------------- parity


@pytest.mark.parametrize("count", [37, 1000])  # serial and parallel loops
def test_numba_step_matches_numpy_reference(count):
    rng = np.random.default_rng(count)
    params = DEEPRACER
    state = CarState(rng.uniform(-10, 10, count), rng.uniform(-10, 10, count), rng.uniform(-math.pi, math.pi, count),
                     rng.uniform(0, params.max_speed, count), rng.uniform(-params.max_steering, params.max_steering, count))
    state.speed[:5] = 0.0  # standing cars
    state.steer[5:10] = 0.0  # straight driving
    cmd_steer = rng.uniform(-0.8, 0.8, count)  # beyond the steering limit too
    cmd_speed = rng.uniform(-0.5, 4.5, count)
    cmd_steer[10:15] = state.steer[10:15]
    for _ in range(3):
        fast = step(state, cmd_steer, cmd_speed, params)
        ref = step_reference(state, cmd_steer, cmd_speed, params)
        for name, a, b in zip(CarState._fields, fast, ref):
            np.testing.assert_allclose(a, b, rtol=0, atol=1e-9, err_msg=name)
        state = fast


def test_step_is_pure():
    state = state_of(3, speed=1.0, steer=0.1)
    before = [a.copy() for a in state]
    step(state, np.zeros(3), np.ones(3), DEEPRACER)
    for a, b in zip(state, before):
        np.testing.assert_array_equal(a, b)


# ---------------------------------------------------------------- footprint and params


def test_footprint_points():
    params = DEEPRACER
    poses = np.array([[1.0, 2.0, 0.0], [0.0, 0.0, math.pi / 2]])
    wheels = wheel_centers(poses, params)
    assert wheels.shape == (2, 4, 2)
    np.testing.assert_allclose(wheels[0], [[1 + params.wheelbase, 2 + params.wheel_track / 2],
                                           [1 + params.wheelbase, 2 - params.wheel_track / 2],
                                           [1.0, 2 + params.wheel_track / 2], [1.0, 2 - params.wheel_track / 2]],
                               atol=1e-12)
    np.testing.assert_allclose(wheels[1, 0], [-params.wheel_track / 2, params.wheelbase], atol=1e-12)
    np.testing.assert_allclose(reference_point(poses, params), [[1.14, 2.0], [0.0, 0.14]], atol=1e-12)
    corners = body_corners(poses[:1], params)[0]
    np.testing.assert_allclose(np.ptp(corners[:, 0]), params.body_length, atol=1e-12)
    np.testing.assert_allclose(np.ptp(corners[:, 1]), params.body_width, atol=1e-12)
    assert corners[:, 0].min() == pytest.approx(1.0 - params.rear_overhang)


def test_vehicle_params_validation():
    assert vehicle_preset("laplab-classic") is DEEPRACER
    assert DEEPRACER.dt == pytest.approx(1 / 15) and DEEPRACER.reference_offset == 0.14
    with pytest.raises(ValueError, match="unknown car"):
        vehicle_preset("f1")
    with pytest.raises(ValueError, match="wheelbase"):
        VehicleParams(wheelbase=0.0)
    with pytest.raises(ValueError, match="substeps"):
        VehicleParams(substeps=0)
    with pytest.raises(ValueError, match="min_speed"):
        VehicleParams(min_speed=5.0)
