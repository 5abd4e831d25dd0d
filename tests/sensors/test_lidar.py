"""Lidar: closed-form ranges on a straight road, numba vs numpy parity, DeepRacer's observation filters."""

from pathlib import Path

import numpy as np
import pytest

from laplab.sensors.lidar import DEFAULT_LIDAR, LidarParams, LidarWalls, scan, scan_reference
from laplab.sensors.lidar_observation import LidarConfig, lidar_observation, lidar_observation_shape, parse_lidar_config

TRACKS = Path(__file__).resolve().parents[2].parent / "shared" / "reference-tracks"


def straight_road(left_y=0.5, right_y=-0.5, length=40.0, points=41):
    """Open (N, 6) route along +x: centre y=0, inner (left) border at left_y, outer (right) at right_y."""
    x = np.linspace(0.0, length, points)
    zero = np.zeros_like(x)
    return np.column_stack([x, zero, x, zero + left_y, x, zero + right_y])


def expected_straight(pose, params, left_y, right_y):
    """Analytic ranges to the walls y=left_y / y=right_y: d / sin(angle), Gazebo range semantics."""
    x, y, yaw = pose
    oy = y + np.sin(yaw) * params.mount_x + np.cos(yaw) * params.mount_y
    theta = yaw + params.beam_angles
    sin = np.sin(theta)
    with np.errstate(divide="ignore"):
        t = np.where(sin > 0, (left_y - oy) / sin, np.where(sin < 0, (right_y - oy) / sin, np.inf))
    return np.where((t >= params.min_range) & (t <= params.max_range), t, params.max_range)


def ellipse_track(a=6.0, b=3.5, width=1.0, n=120):
    s = np.linspace(0, 2 * np.pi, n)
    centre = np.column_stack([a * np.cos(s), b * np.sin(s)])
    normal = np.column_stack([b * np.cos(s), a * np.sin(s)])
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    route = np.hstack([centre, centre - normal * width / 2, centre + normal * width / 2])
    route[-1] = route[0]
    return route


def random_poses(route, n, seed):
    rng = np.random.default_rng(seed)
    rows = rng.integers(0, len(route) - 1, n)
    xy = route[rows, 0:2] + rng.normal(0.0, 0.15, (n, 2))
    return np.column_stack([xy, rng.uniform(-np.pi, np.pi, n)])


@pytest.mark.parametrize("pose", [(20.0, 0.0, 0.0), (18.0, 0.1, 0.3), (22.0, -0.2, -2.5), (20.0, 0.25, np.pi)])
def test_straight_road_matches_closed_form(pose):
    walls = LidarWalls.from_track(straight_road())
    ranges = scan(walls, np.array([pose]))
    assert ranges.shape == (1, 64) and ranges.dtype == np.float32
    np.testing.assert_allclose(ranges[0], expected_straight(pose, DEFAULT_LIDAR, 0.5, -0.5), atol=1e-5)


def test_beam_layout_is_deepracer():
    angles = DEFAULT_LIDAR.beam_angles
    assert angles.shape == (64,)
    assert np.degrees(angles[0]) == pytest.approx(-150.0, abs=1e-3)
    assert np.degrees(angles[-1]) == pytest.approx(150.0, abs=1e-3)
    # Beam 0 looks right: on a road with the right wall near, it reads the right wall.
    ranges = scan(LidarWalls.from_track(straight_road(left_y=5.0, right_y=-0.3)), np.array([[20.0, 0.0, 0.0]]))
    assert ranges[0, 0] == pytest.approx(0.3 / np.sin(np.radians(150.0)), abs=1e-4)


def test_out_of_range_reads_max_range():
    walls = LidarWalls.from_track(straight_road(left_y=20.0, right_y=-20.0))
    ranges = scan(walls, np.array([[20.0, 0.0, 0.0], [20.0, 0.0, 1.0]]))
    assert np.all(ranges == DEFAULT_LIDAR.max_range)
    short = LidarParams(max_range=3.0)
    ranges = scan(LidarWalls.from_track(straight_road(2.0, -2.0)), np.array([[20.0, 0.0, 0.0]]), short)
    np.testing.assert_allclose(ranges[0], expected_straight((20.0, 0.0, 0.0), short, 2.0, -2.0), atol=1e-5)
    assert ranges.max() == 3.0


def test_wall_nearer_than_min_range_is_not_seen():
    # Left wall 0.1 m from the sensor: beams that would hit it inside 0.15 m pass it, as in Gazebo.
    walls = LidarWalls.from_track(straight_road(left_y=0.1, right_y=-0.5))
    ranges = scan(walls, np.array([[20.0, 0.0, 0.0]]))[0]
    left_steep = np.sin(DEFAULT_LIDAR.beam_angles) > 0.1 / 0.15
    assert left_steep.any() and np.all(ranges[left_steep] == 12.0)
    np.testing.assert_allclose(ranges, expected_straight((20.0, 0.0, 0.0), DEFAULT_LIDAR, 0.1, -0.5), atol=1e-5)


def test_rigid_motion_of_the_world_does_not_change_ranges():
    route, pose = straight_road(), np.array([20.0, 0.1, 0.4])
    angle, shift = 0.7, np.array([3.0, -5.0])
    rot = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    moved = np.hstack([route[:, k:k + 2] @ rot.T + shift for k in (0, 2, 4)])
    moved_pose = np.array([*(rot @ pose[:2] + shift), pose[2] + angle])
    a = scan(LidarWalls.from_track(route), pose[None])
    b = scan(LidarWalls.from_track(moved), moved_pose[None])
    np.testing.assert_allclose(a, b, atol=1e-5)


@pytest.mark.parametrize("cell_size", [0.1, 0.25, 1.0, 50.0])
def test_grid_kernel_matches_brute_force_on_a_loop(cell_size):
    route = ellipse_track()
    walls = LidarWalls.from_track(route, cell_size=cell_size)
    poses = random_poses(route, 300, seed=1)
    poses[:5, :2] = [[30.0, 30.0], [-30.0, 0.0], [0.0, 0.0], [6.0, 0.0], [0.0, -20.0]]  # outside and on walls
    np.testing.assert_allclose(scan(walls, poses), scan_reference(walls, poses), atol=1e-5)
    np.testing.assert_allclose(scan(walls, poses[:3]), scan_reference(walls, poses[:3]), atol=1e-5)  # serial kernel


def test_grid_kernel_matches_brute_force_on_reinvent_base():
    path = TRACKS / "reinvent_base.npy"
    if not path.is_file():
        pytest.skip("shared reference tracks not present")
    route = np.load(path)
    walls = LidarWalls.from_track(route[:, 0:2], route[:, 2:4], route[:, 4:6])
    poses = random_poses(route, 512, seed=2)
    np.testing.assert_allclose(scan(walls, poses), scan_reference(walls, poses), atol=1e-5)


def test_track_object_and_axis_aligned_rays():
    class TrackLike:
        route = ellipse_track(4.0, 4.0, n=9)  # octagon: beams parallel to some walls
        centerline, inner, outer = route[:, 0:2], route[:, 2:4], route[:, 4:6]

    walls = LidarWalls.from_track(TrackLike())
    poses = np.array([[0.0, 4.0, 0.0], [4.0, 0.0, np.pi / 2], [0.0, -4.0, np.pi], [2.8, 2.8, 3 * np.pi / 4]])
    np.testing.assert_allclose(scan(walls, poses), scan_reference(walls, poses), atol=1e-5)


def test_noise_is_seeded_gaussian_and_spares_misses():
    walls = LidarWalls.from_track(straight_road())
    poses = np.tile([[20.0, 0.0, 0.0]], (200, 1))
    exact = scan(walls, poses)
    noisy_a = scan(walls, poses, rng=np.random.default_rng(7))
    noisy_b = scan(walls, poses, rng=np.random.default_rng(7))
    np.testing.assert_array_equal(noisy_a, noisy_b)
    hit = exact < 12.0
    assert np.std(noisy_a[hit] - exact[hit]) == pytest.approx(0.01, rel=0.05)
    assert np.all(noisy_a[~hit] == 12.0) and noisy_a.min() >= 0.15
    np.testing.assert_array_equal(scan(walls, poses[:1]), exact[:1])  # no rng -> exact


def test_bad_input_is_reported():
    walls = LidarWalls.from_track(straight_road())
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        scan(walls, np.zeros(3))
    with pytest.raises(ValueError, match="min_range"):
        LidarParams(min_range=13.0)
    with pytest.raises(ValueError, match=r"\(N, 6\)"):
        LidarWalls.from_track(np.zeros((10, 4)))


def test_lidar_observation_clips():
    ranges = np.array([[0.05, 0.15, 0.5, 1.0, 3.0, 12.0, 0.7, 0.2] * 8])
    obs = lidar_observation("LIDAR", ranges)
    assert obs.shape == (1, 64) and obs.dtype == np.float32
    np.testing.assert_allclose(obs[0, :8], [0.15, 0.15, 0.5, 1.0, 1.0, 1.0, 0.7, 0.2])


def test_sector_lidar_is_binary_per_sector_of_eight_beams():
    ranges = np.full(64, 5.0)
    ranges[3] = 0.49     # sector 0
    ranges[20] = 0.5     # sector 2: not below the 0.5 m clip
    ranges[63] = 0.16    # sector 7
    obs = lidar_observation("SECTOR_LIDAR", ranges)
    np.testing.assert_array_equal(obs, [1, 0, 0, 0, 0, 0, 0, 1])
    assert lidar_observation("SECTOR_LIDAR", np.stack([ranges, ranges * 0 + 12])).shape == (2, 8)


def test_discretized_sector_lidar_one_hot_bins():
    ranges = np.full(64, 12.0)
    ranges[0:8] = [3, 3, 0.2, 3, 3, 3, 3, 3]  # sector 0: nearest 0.2 m -> bin 0 of 0.25 m bins
    ranges[8] = 0.3                            # sector 1 -> bin 1
    ranges[16] = 1.99                          # sector 2 -> bin 7
    ranges[24] = 2.0                           # sector 3: at the clip -> nothing detected
    obs = lidar_observation("DISCRETIZED_SECTOR_LIDAR", ranges).reshape(8, 8)
    expected = np.zeros((8, 8))
    expected[0, 0] = expected[1, 1] = expected[2, 7] = 1
    np.testing.assert_array_equal(obs, expected)
    custom = {"num_sectors": 4, "num_values_per_sector": 2, "clipping_dist": 1.0}
    obs = lidar_observation("DISCRETIZED_SECTOR_LIDAR", ranges[None], custom)
    np.testing.assert_array_equal(obs, [[1, 0, 0, 0, 0, 0, 0, 0]])  # 4 sectors of 16 beams, 0.5 m bins


def test_observation_shapes_and_config_parsing():
    assert lidar_observation_shape("LIDAR") == (64,)
    assert lidar_observation_shape("SECTOR_LIDAR") == (8,)
    assert lidar_observation_shape("DISCRETIZED_SECTOR_LIDAR") == (64,)
    assert lidar_observation_shape("DISCRETIZED_SECTOR_LIDAR", {"num_sectors": 16, "num_values_per_sector": 3}) == (48,)
    assert parse_lidar_config({"clipping_dist": 50, "num_values_per_sector": 0}) == LidarConfig(8, 1, 12.0)
    for bad, message in (({"num_sectors": 5}, "divide"), ({"num_sectors": "8"}, "integer"),
                         ({"clip": 1.0}, "unknown key")):
        with pytest.raises(ValueError, match=message):
            parse_lidar_config(bad)
    with pytest.raises(ValueError, match="unknown lidar sensor"):
        lidar_observation("FRONT_FACING_CAMERA", np.ones(64))
