"""Evaluation under DeepRacer's object-avoidance rules: a crash costs the collision penalty and puts
the car back 1 m behind the box in the other lane; the trial table counts the collision."""

from __future__ import annotations

import numpy as np
import pytest

from laplab.env.action_space import ActionSpace
from laplab.env.metadata import ModelMetadata
from laplab.env.spec import model_spec
from laplab.evaluate import EvaluationSettings, evaluate_policy
from laplab.sim.race_type import RaceType
from laplab.sim.state import IN_PROGRESS
from laplab.track.geometry import track_from_route
from laplab.track.projection import project_points, track_arrays
from laplab.vehicle.params import CLASSIC

METADATA = ModelMetadata(action_space=ActionSpace("continuous", (), (-30.0, 30.0), (0.0, 2.0)))
BOX_AT = 0.3  # fraction of the lap, inner lane


@pytest.fixture(scope="module")
def wide_track(stadium_route):
    return track_from_route(stadium_route(width=2.0), "wide-stadium")


class LaneDriver:
    """Drives the box's lane at 1.5 m/s until it is put back (a jump), then the centre line."""

    def bind(self, sim):
        self.sim, self.last, self.reset_at = sim, None, None

    def __call__(self, observations):
        sim, st = self.sim, self.sim.state
        cars = np.flatnonzero(st.status == IN_PROGRESS)
        xy = np.column_stack([st.x[cars], st.y[cars]])
        if self.last is not None and self.reset_at is None and np.hypot(*(xy[0] - self.last)) > 0.15:
            self.reset_at = (float(st.ref_x[cars[0]]), float(st.ref_y[cars[0]]))
        self.last = xy[0]
        geo = sim.arrays[0]
        from laplab.sim.race_field import lane_pose
        frac = 0.0 if self.reset_at is not None else sim.field.frac[cars[0], 0]
        tx, ty, _ = lane_pose(st.arc[cars[0]] + 0.6, frac, 0.0, geo.centerline, geo.arc_length, geo.left_width,
                              geo.right_width)
        dx, dy = tx - st.x[cars[0]], ty - st.y[cars[0]]
        c, s = np.cos(st.yaw[cars[0]]), np.sin(st.yaw[cars[0]])
        fwd, left = c * dx + s * dy, -s * dx + c * dy
        steer = np.arctan(2.0 * sim.vehicle.wheelbase * left / max(fwd ** 2 + left ** 2, 1e-9))
        steer = np.clip(steer, -sim.vehicle.max_steering, sim.vehicle.max_steering)
        return np.array([[np.degrees(steer) / 30.0, 0.5]])


def test_a_crash_costs_the_penalty_and_resets_behind_the_box(wide_track):
    race = RaceType("object_avoidance", object_positions=((BOX_AT, 1),))
    driver = LaneDriver()
    result = evaluate_policy(driver, wide_track, EvaluationSettings(trials=1, force=True), spec=model_spec(METADATA),
                             vehicle=CLASSIC, race=race)
    trial = result.trials[0]
    assert trial.status == "lap_complete"
    assert trial.crash_count == 1 and trial.reset_count == 1 and trial.penalty_time == 5.0
    assert driver.reset_at is not None
    sim = driver.sim
    box = np.array([[sim.obstacles.x[0, 0], sim.obstacles.y[0, 0]]])
    arrays = track_arrays(wide_track)
    box_proj = project_points(arrays, box)
    car_proj = project_points(arrays, np.array([driver.reset_at]))
    assert car_proj.arc_length[0] == pytest.approx(box_proj.arc_length[0] - 1.0, abs=0.05)
    assert np.sign(car_proj.lateral[0]) == -np.sign(box_proj.lateral[0])  # the other lane
    assert result.to_dict()["race_type"]["kind"] == "object_avoidance"
    assert (result.trace["obstacle_crash_counter"][-1]) == 1


def test_time_trial_evaluations_record_no_race_type(wide_track):
    result = evaluate_policy(lambda obs: np.tile([0.0, 0.0], (len(obs), 1)), wide_track,
                             EvaluationSettings(trials=1, force=True, max_trial_time=1.0), spec=model_spec(METADATA),
                             vehicle=CLASSIC)
    assert result.to_dict()["race_type"] is None


def test_topdown_pictures_show_the_boxes(wide_track):
    from laplab.evaluate.video import trial_obstacles
    from laplab.sensors.render import draw_topdown
    race = RaceType("object_avoidance", object_positions=((0.3, 1), (0.7, -1)))
    result = evaluate_policy(LaneDriver(), wide_track, EvaluationSettings(trials=1, force=True, max_trial_time=2.0),
                             spec=model_spec(METADATA), vehicle=CLASSIC, race=race)
    assert result.obstacles.shape == (len(result.trace["episode"]), 2, 7)
    trial = trial_obstacles(result, 0, 10)
    assert trial.x.shape == (10, 2)  # a row per frame
    plain = draw_topdown(wide_track)
    with_boxes = draw_topdown(wide_track, obstacles=trial.rows(slice(0, 1)))
    brown = (with_boxes == np.array([123, 97, 79], dtype=np.uint8)).all(axis=-1)
    assert brown.sum() > 20 and not (plain == np.array([123, 97, 79], dtype=np.uint8)).all(axis=-1).any()


def test_the_video_camera_sees_the_boxes(wide_track):
    from laplab.evaluate.video import trial_obstacles, trial_poses
    from laplab.sensors.camera import FRONT_FACING_CAMERA, render_camera
    from laplab.sensors.look import texture_for_track
    race = RaceType("object_avoidance", object_positions=((0.1, 1), (0.6, -1)))
    result = evaluate_policy(LaneDriver(), wide_track, EvaluationSettings(trials=1, force=True, max_trial_time=2.0),
                             spec=model_spec(METADATA), vehicle=CLASSIC, race=race)
    poses, _ = trial_poses(result, 0)
    texture = texture_for_track(wide_track)
    plain = render_camera(texture, poses[:5], FRONT_FACING_CAMERA)
    seen = render_camera(texture, poses[:5], FRONT_FACING_CAMERA, obstacles=trial_obstacles(result, 0, 5))
    assert (plain != seen).any()  # the box ahead is in the frames the video shows


def test_an_evaluation_drives_the_race_it_is_given(tmp_path, monkeypatch):
    """A console race's evaluation sets its own objects (EvaluationSettings.race_type), whatever the
    model trained with; bad race settings name race_type."""
    from laplab.evaluate.trials import EvaluationError, evaluate_model
    from laplab.train.config import TrainConfig
    from laplab.train.jobs import create_training
    monkeypatch.setenv("LAPLAB_HOME", str(tmp_path / "home"))
    create_training("plain", TrainConfig(track="oval")).close()
    race = {"kind": "object_avoidance", "objects": 2, "collision_penalty": 3.0}
    result, _ = evaluate_model("plain", EvaluationSettings(trials=1, max_trial_time=3.0, race_type=race))
    assert result.race_type["kind"] == "object_avoidance" and result.race_type["objects"] == 2
    assert result.settings.crash_penalty == 3.0  # the race's collision penalty
    with pytest.raises(EvaluationError) as refused:
        EvaluationSettings(race_type={"kind": "drag_race"})
    assert refused.value.field == "race_type"
