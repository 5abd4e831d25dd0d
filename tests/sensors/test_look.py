"""Camera looks: a DeepRacer route's rendered frame against its simapp materials, looks by route name
without network, the default look's notice, the grey conversion, and randomisation on a look."""

import json
import logging
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from laplab.sensors.camera import FRONT_FACING_CAMERA, camera_rays, render_camera
from laplab.sensors.look import DESIGN_LOOKS, LOOKS_FILE, look_for_track, simapp_looks, texture_for_track
from laplab.sensors.randomize import RandomizationParams, build_randomized_texture, render_randomized, \
    sample_randomization
from laplab.sensors.texture import luma601
from laplab.sensors.walls import Light, ground_gain
from laplab.track.registry import import_track, load_track

SHARED = Path(__file__).resolve().parents[2].parent / "shared"
TRACKS = SHARED / "reference-tracks"
FRAMES = SHARED / "real-deepracer" / "frames"
# reinvent_base's materials as deepracer-simapp (b7599b42) has them, read by hand from its files:
# meshes/reinvent/textures/{road,outerLine,centerLine,field,wall}.png mean RGB, reinvent_base.dae's walls
# (1 m high, x -0.587..8.575, y -0.613..5.795), the lines' widths (3 in tape, 1 in dashes of 2 in).
SIMAPP_ALBEDO = {"road": (36.1, 48.5, 64.0), "border": (194.4, 193.6, 189.8), "center": (194.4, 116.5, 0.0),
                 "field": (95.2, 135.6, 104.3), "wall": (36.0, 70.0, 81.0)}
# reinvent_base.world: Gazebo's sun (0.8 diffuse along (-0.5, 0.1, -0.9)) and a point light of 0.225
# at (0, 0, 15) with attenuation 0.4 + 0.01 d; a floor at the room's centre (4.0, 2.6, 0) gets
# 0.8 * 0.9 / |(-0.5, 0.1, -0.9)| + 0.225 * (15 / d) / (0.4 + 0.01 d), d = |(4.0, 2.6, -15)|.
_D = math.sqrt(3.994 ** 2 + 2.591 ** 2 + 15.0 ** 2)
FLOOR_GAIN = 0.8 * 0.9 / math.sqrt(0.25 + 0.01 + 0.81) + 0.225 * (15.0 / _D) / (0.4 + 0.01 * _D)


def reinvent_base():
    path = TRACKS / "reinvent_base.npy"
    if not path.is_file():
        pytest.skip(f"{path} is absent")
    return load_track(path)


def test_the_look_file_holds_reinvent_base_as_the_simapp_draws_it():
    entry = simapp_looks()["reinvent_base"]
    for kind in ("road", "border", "center", "field"):
        assert np.allclose(entry[kind]["rgb"], SIMAPP_ALBEDO[kind], atol=0.6), kind
    assert np.allclose(entry["wall"]["rgb"], SIMAPP_ALBEDO["wall"], atol=0.6)
    assert entry["wall"]["height"] == pytest.approx(1.0)
    assert entry["wall"]["room"] == pytest.approx([-0.587, -0.613, 8.575, 5.795], abs=1e-3)
    assert entry["border_width"] == pytest.approx(0.0762, abs=5e-4)  # 3 inches
    assert entry["center_width"] == pytest.approx(0.0254, abs=5e-4)  # 1 inch
    assert entry["dash_length"] == pytest.approx(0.0508, abs=2e-3)  # 2 inches on, 2 off
    assert entry["dash_gap"] == pytest.approx(0.0508, abs=2e-3)
    lights = look_for_track(reinvent_base()).params.wall_lights
    assert ground_gain(lights, (-0.587, -0.613, 8.575, 5.795))[0] == pytest.approx(FLOOR_GAIN, rel=1e-3)


def test_a_rendered_reinvent_base_frame_shows_the_simapp_colours_at_known_pixels():
    """On the start straight, heading +x, centred: pixels that the pinhole model puts on the road, a
    dash, the right border tape and the field show the albedo times the floor's gain; the wall ahead
    (east, x = 8.575, inward normal -x) shows its albedo times the point light's gain there."""
    track = reinvent_base()
    texture = texture_for_track(track)
    camera = FRONT_FACING_CAMERA.with_(grayscale=False, mipmap=False)
    x0, y0 = 3.0, float(np.interp(3.0, track.centerline[:12, 0], track.centerline[:12, 1]))
    frame = render_camera(texture, [[x0, y0, 0.0]], camera)[0].astype(float)
    lit = lambda kind: np.clip(np.asarray(SIMAPP_ALBEDO[kind]) * FLOOR_GAIN, 0, 255)
    rays = camera_rays(camera)

    def pixel(forward, left):  # (row, col) whose ray meets the ground nearest (forward, left), car frame
        gap = np.where(rays.hits_ground, np.hypot(rays.ground_x - forward, rays.ground_y - left), np.inf)
        assert gap.min() < 0.05, "the point is out of view"  # rows are ~3 cm apart at 1.5 m
        return divmod(int(np.argmin(gap)), camera.width)
    # Road between the centre line and the right tape; tape 0.34 m right; field 0.75 m right.
    grain = 3 * 6.1 * FLOOR_GAIN  # three standard deviations of the road texture's 5 mm grain
    assert np.abs(frame[pixel(1.0, -0.2)] - lit("road")).max() < grain
    assert np.abs(frame[pixel(1.3, -0.343)] - lit("border")).max() < 3 * 14.2 * FLOOR_GAIN
    assert np.abs(frame[pixel(1.6, -0.75)] - lit("field")).max() < 3 * 8.8 * FLOOR_GAIN
    # The dashes (2 in on, 2 in off) start 0.0527 m along the centre line, whose row 0 is at x = 3.06:
    # the fourth runs over x 3.4175..3.4683 (0.443 m ahead of the car at x = 3.0), a gap follows.
    assert np.abs(frame[pixel(0.443, 0.0)] - lit("center")).max() < 12
    assert np.abs(frame[pixel(0.494, 0.0)] - lit("road")).max() < grain
    row = 15  # ~5 degrees above the horizon: the east wall ~0.6 m up, 5.6 m ahead
    up = math.atan((0.5 * camera.height - row - 0.5) / camera.focal_length) - camera.pitch
    east = np.array([8.575, y0, camera.mount_up + (8.575 - x0 - camera.mount_forward) * math.tan(up)])
    offset = np.array([0.0, 0.0, 15.0]) - east
    d = np.linalg.norm(offset)
    wall = np.asarray(SIMAPP_ALBEDO["wall"]) * 0.225 * (-offset[0] / d) / (0.4 + 0.01 * d)
    top = frame[row, 80]
    assert np.abs(top - wall).max() < 3


def test_grey_frame_is_the_rounded_601_luma_of_the_colour_frame_by_hand():
    track = reinvent_base()
    texture = texture_for_track(track)
    pose = [[3.0, 0.68, 0.0]]
    rgb = render_camera(texture, pose, FRONT_FACING_CAMERA.with_(grayscale=False))[0]
    grey = render_camera(texture, pose, FRONT_FACING_CAMERA)[0]
    r, g, b = (int(v) for v in rgb[100, 60])
    assert grey[100, 60] == math.floor(0.299 * r + 0.587 * g + 0.114 * b + 0.5)
    assert int(luma601([200, 100, 0])) == 119  # 59.8 + 58.7 + 0 = 118.5 -> 119 (rounded half up)


def test_an_imported_route_gets_its_look_offline(tmp_path, monkeypatch):
    monkeypatch.setenv("LAPLAB_HOME", str(tmp_path))
    source = TRACKS / "reInvent2019_wide_ccw.npy"
    if not source.is_file():
        pytest.skip(f"{source} is absent")
    import urllib.request
    monkeypatch.setattr(urllib.request, "urlopen", lambda *a, **k: pytest.fail("network used"))
    import_track(source)
    track = load_track("reInvent2019_wide_ccw")
    look = look_for_track(track)
    assert look.source == "deepracer-simapp" and look.notice is None
    entry = json.loads(LOOKS_FILE.read_text())["routes"]["reInvent2019_wide_ccw"]
    assert look.params.room == pytest.approx(entry["wall"]["room"])
    backwards = look_for_track(track.reversed()).params  # name@reversed: the same world, dashes from the end
    assert replace(backwards, dash_offset=look.params.dash_offset) == look.params
    period = look.params.dash_length + look.params.dash_gap
    length = float(np.linalg.norm(np.diff(track.centerline, axis=0), axis=1).sum())
    ends = (look.params.dash_offset + look.params.dash_length) % period  # a dash ends here, forwards ...
    wrap = (length - backwards.dash_offset - ends) % period  # ... and one starts here backwards
    assert min(wrap, period - wrap) < 1e-9


def test_an_unknown_route_gets_the_default_look_and_says_so(caplog):
    theta = np.linspace(0, 2 * np.pi, 60)
    ring = lambda r: np.column_stack([r * np.cos(theta), r * np.sin(theta)])
    route = np.hstack([ring(2.0), ring(1.6), ring(2.4)])
    with caplog.at_level(logging.WARNING, logger="laplab.camera"):
        texture = texture_for_track(route, name="my_garage_loop")
        texture_for_track(route, name="my_garage_loop")  # said once per route and process
    assert len(caplog.records) == 1
    message = caplog.records[0].getMessage()
    assert "my_garage_loop" in message and "default" in message and "\n" not in message
    assert look_for_track(route, "my_garage_loop").source == "default"
    assert texture.num_variants == 1


@pytest.mark.parametrize("name", sorted(DESIGN_LOOKS))
def test_built_in_designs_have_a_look_of_their_own(name, caplog):
    with caplog.at_level(logging.WARNING, logger="laplab.camera"):
        look = look_for_track(load_track(name))
    assert look.notice is None and "DeepRacer's style" in look.source and not caplog.records
    assert look.params.wall_lights


def test_light_gain_of_a_point_light_by_hand():
    light = Light("point", (0.5, 0.5, 0.5), position=(0.0, 0.0, 3.0), attenuation=(1.0, 0.5, 0.0))
    gain = light.gain(np.array([4.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0]))
    assert gain == pytest.approx([0.5 * 0.6 / 3.5] * 3)  # cos = 3/5, attenuation 1 / (1 + 0.5 * 5)


def test_randomisation_keeps_working_on_a_deepracer_look():
    track = reinvent_base()
    params = look_for_track(track).params
    rand = RandomizationParams(enabled=True, texture_variants=3)
    rng = np.random.default_rng(3)
    texture = build_randomized_texture(track, params, rand, rng)
    assert texture.num_variants == 4 and texture.params.wall_lights == params.wall_lights
    poses = np.array([[3.0, 0.68, 0.0]] * 8)
    draw = sample_randomization(rng, 8, rand, FRONT_FACING_CAMERA, texture.num_variants)
    frames = render_randomized(texture, poses, FRONT_FACING_CAMERA, draw, rng)
    assert frames.shape == (8, 120, 160) and frames.dtype == np.uint8
    assert len({frame.tobytes() for frame in frames}) == 8
    plain = render_camera(texture, poses[:1])[0]
    assert 40 < plain[60:].mean() < 120  # the ground of the look, not the old grey one


def test_reinvent_base_asphalt_matches_a_real_simulator_frame():
    """dr-demo-1's asphalt (its bottom-left corner, lit by the world's lights) against the look's road
    colour (albedo times the floor's gain): within 8 levels a channel."""
    frames = sorted(FRAMES.glob("dr-demo-*.png"))
    if not frames:
        pytest.skip(f"no frames in {FRAMES}")
    from PIL import Image
    real = np.asarray(Image.open(frames[0]).convert("RGB")).astype(float)
    road_real = real[400:, :60].mean(axis=(0, 1))  # bottom-left corner: asphalt in dr-demo-1
    palette = look_for_track(reinvent_base()).params.palette
    assert np.abs(road_real - np.asarray(palette.road)).max() < 8


def test_every_route_laplab_can_fetch_has_a_look_or_a_stated_reason():
    from laplab.track.fetch import shipped_route_names
    skipped = json.loads(LOOKS_FILE.read_text())["skipped"]
    looks = simapp_looks()
    assert [name for name in shipped_route_names() if name not in looks and name not in skipped] == []
    assert len(looks) >= 120
