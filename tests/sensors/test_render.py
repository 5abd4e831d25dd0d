"""Top-down renderer, lidar polar plot and episode videos (GIF always, MP4 when imageio-ffmpeg is there)."""

import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from laplab.sensors.render import DEFAULT_RENDER, RenderParams, TopdownRenderer, draw_lidar_polar, draw_topdown, renderer_for
from laplab.sensors.video import VideoParams, compose_frame, format_overlay, write_episode_video

TRACKS = Path(__file__).resolve().parents[2].parent / "shared" / "reference-tracks"


def ring_track(radius=3.0, width=1.0, n=80):
    s = np.linspace(0, 2 * np.pi, n)
    unit = np.column_stack([np.cos(s), np.sin(s)])
    route = np.hstack([radius * unit, (radius - width / 2) * unit, (radius + width / 2) * unit])
    route[-1] = route[0]
    return route


def pixel(image, renderer, xy):
    col, row = np.round(renderer.to_pixels(np.asarray(xy, dtype=float))).astype(int)
    return image[row, col]


def test_topdown_draws_road_grass_and_cars_where_the_world_says():
    route = ring_track()
    renderer = TopdownRenderer(route, RenderParams(width_px=400))
    image = renderer.draw(np.array([[3.0, 0.0, np.pi / 2]]), camera_fov=None)
    assert image.dtype == np.uint8 and image.shape == (400, 400, 3)  # square track -> square image
    assert tuple(pixel(image, renderer, [0.0, 0.0])) == DEFAULT_RENDER.grass          # inside the ring
    assert tuple(pixel(image, renderer, [-3.2, 0.3])) == DEFAULT_RENDER.road          # on the road
    assert tuple(pixel(image, renderer, [3.0, 0.0])) == DEFAULT_RENDER.car_colors[0]  # car body (behind the nose)
    assert tuple(pixel(image, renderer, [3.2, 0.4])) == DEFAULT_RENDER.road           # ahead of the car


def test_car_corners_follow_vehicle_geometry():
    renderer = TopdownRenderer(ring_track())
    v = DEFAULT_RENDER.vehicle
    corners = renderer.car_corners(np.array([[1.0, 2.0, np.pi / 2]]))[0]
    front, rear, half = v.body_length - v.rear_overhang, -v.rear_overhang, v.body_width / 2
    np.testing.assert_allclose(corners, [[1 + half, 2 + rear], [1 + half, 2 + front],
                                         [1 - half, 2 + front], [1 - half, 2 + rear]], atol=1e-12)


def test_camera_wedge_paths_and_lidar_change_the_right_pixels():
    route = ring_track()
    renderer = TopdownRenderer(route, RenderParams(width_px=400))
    pose = np.array([[3.0, 0.0, np.pi / 2]])
    plain = renderer.draw(pose, camera_fov=None)
    wedge = renderer.draw(pose, camera_fov=1.13)
    assert not np.array_equal(pixel(plain, renderer, [3.0, 0.8]), pixel(wedge, renderer, [3.0, 0.8]))  # ahead
    assert np.array_equal(pixel(plain, renderer, [3.0, -0.8]), pixel(wedge, renderer, [3.0, -0.8]))    # behind
    path = np.column_stack([np.full(20, -3.0), np.linspace(-1.0, 1.0, 20)])
    with_path = renderer.draw(pose, [np.zeros((0, 2)), path], camera_fov=None)
    col, row = np.round(renderer.to_pixels(np.array([-3.0, 0.0]))).astype(int)
    assert (with_path[row - 2:row + 3, col - 2:col + 3] != plain[row - 2:row + 3, col - 2:col + 3]).any()
    with_lidar = renderer.draw(pose, camera_fov=None, lidar_ranges=np.full((1, 64), 0.4))
    assert (with_lidar != plain).any(axis=2).sum() > (plain != plain).sum() + 50


def test_background_is_cached_per_track_and_open_tracks_render():
    route = ring_track()
    assert renderer_for(route) is renderer_for(route.copy())
    assert renderer_for(route) is not renderer_for(ring_track(radius=4.0))
    x = np.linspace(0, 10, 11)
    straight = np.column_stack([x, 0 * x, x, 0 * x + 0.5, x, 0 * x - 0.5])
    image = draw_topdown(straight, np.array([[5.0, 0.0, 0.0]]), [np.array([[1.0, 0.0], [4.0, 0.1]])])
    renderer = renderer_for(straight)
    assert tuple(pixel(image, renderer, [7.0, 0.3])) == DEFAULT_RENDER.road
    assert tuple(pixel(image, renderer, [7.0, 0.9])) == DEFAULT_RENDER.grass


def test_reinvent_base_start_line_is_chequered(tmp_path):
    path = TRACKS / "reinvent_base.npy"
    if not path.is_file():
        pytest.skip("shared reference tracks not present")
    route = np.load(path)
    renderer = renderer_for(route)
    image = renderer.draw()
    col, row = np.round(renderer.to_pixels(route[0, 0:2])).astype(int)
    patch = image[row - 20:row + 20, col - 8:col + 4].reshape(-1, 3).astype(int)
    assert (patch.sum(1) > 700).any() and (patch.sum(1) < 90).any()
    Image.fromarray(image).save(tmp_path / "reinvent_base.png")


def test_lidar_polar_puts_beams_where_the_angles_say():
    angles = np.array([0.0, np.pi / 2, -np.pi / 2, 2.0])
    ranges = np.array([1.0, 2.0, 12.0, 0.5])
    image = draw_lidar_polar(ranges, angles, size=200, display_range=2.5)
    assert image.shape == (200, 200, 3) and image.dtype == np.uint8
    scale = (200 / 2 - 4) / 2.5
    front = image[round(100 - 1.0 * scale), 100]
    left = image[100, round(100 - 2.0 * scale)]
    assert front[0] > 200 and front[1] < 120 and left[0] > 200 and left[1] < 120  # red hit dots
    assert image[100, round(100 + 2.0 * scale)][0] < 150                            # the miss: faint line only
    assert draw_lidar_polar(np.full(64, 0.8)).shape == (240, 240, 3)
    with pytest.raises(ValueError, match="must match"):
        draw_lidar_polar(np.ones(5), np.ones(4))


def frames(count=5, height=40, width=60):
    rng = np.random.default_rng(0)
    top = rng.integers(0, 255, (count, height, width, 3), dtype=np.uint8)
    camera = rng.integers(0, 255, (count, 12, 16), dtype=np.uint8)
    overlays = {"speed": np.linspace(0.5, 2, count), "steering": np.linspace(-30, 30, count),
                "progress": np.linspace(0, 4, count), "reward": np.ones(count)}
    return top, camera, overlays


def test_gif_has_every_frame_side_by_side_with_text(tmp_path):
    top, camera, overlays = frames()
    written = write_episode_video(tmp_path / "episode.gif", top, camera, overlays)
    with Image.open(written) as gif:
        assert gif.n_frames == 5
        # 60 px top-down + camera 16 px upscaled x3 (40 // 12); 40 px high + a 28 px text bar.
        assert gif.size == (60 + 48, 40 + 28)


def test_mp4_when_imageio_ffmpeg_is_installed(tmp_path):
    imageio_ffmpeg = pytest.importorskip("imageio_ffmpeg")
    top, camera, overlays = frames(count=6)
    written = write_episode_video(tmp_path / "episode.mp4", top, camera[..., None],
                                  [dict(zip(overlays, v)) for v in zip(*overlays.values())])
    assert written.suffix == ".mp4"
    count, _ = imageio_ffmpeg.count_frames_and_secs(str(written))
    reader = imageio_ffmpeg.read_frames(str(written))
    meta = next(reader)
    reader.close()
    assert count == 6 and tuple(meta["size"]) == (112, 80)  # 108 x 68 padded to blocks of 16


def test_mp4_falls_back_to_gif_without_imageio_ffmpeg(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "imageio_ffmpeg", None)
    top, camera, _ = frames(count=3)
    with pytest.warns(UserWarning, match="imageio-ffmpeg"):
        written = write_episode_video(tmp_path / "episode.mp4", top, camera)
    assert written == tmp_path / "episode.gif" and written.is_file()


def test_compose_accepts_gray_stereo_and_rgb_cameras():
    top = np.zeros((120, 100, 3), np.uint8)
    params = VideoParams(camera_scale=1)
    assert compose_frame(top, np.zeros((120, 160), np.uint8), "", params).shape == (120 + 28, 260, 3)
    assert compose_frame(top, np.zeros((120, 160, 2), np.uint8), "", params).shape == (148, 420, 3)
    assert compose_frame(top, np.zeros((60, 80, 3), np.uint8)).shape == (148, 260, 3)  # upscaled x2
    with pytest.raises(ValueError, match="camera frames"):
        compose_frame(top, np.zeros((120, 160, 4), np.uint8))


def test_overlay_text_and_bad_input():
    text = format_overlay(12, {"speed": 1.8, "steering_angle": -12, "progress": 34.5, "reward": 0.87, "done": False})
    assert text == "step 12   speed 1.80 m/s   steering -12.0\N{DEGREE SIGN}   progress 34.5 %   reward 0.870   done False"
    top, camera, overlays = frames()
    with pytest.raises(ValueError, match="one value per frame"):
        write_episode_video("x.gif", top, camera, {"speed": [1.0, 2.0]})
    with pytest.raises(ValueError, match="camera frames"):
        write_episode_video("x.gif", top, camera[:2])
    with pytest.raises(ValueError, match=r"\.mp4 or \.gif"):
        write_episode_video("x.avi", top)
