"""Camera: pinhole geometry derived by hand on a straight road, numba vs numpy parity, stereo,
sensor names, texture classes and seeded domain randomisation."""

import math
from pathlib import Path

import numpy as np
import pytest

from laplab.sensors.camera import (FRONT_FACING_CAMERA, HUMAN_CAMERA, LEFT_CAMERA, STEREO_CAMERAS, CameraParams,
                                   camera_for_sensor, camera_rays, render_camera, render_cameras, sample_levels)
from laplab.sensors.randomize import (RandomizationParams, apply_photometric, build_randomized_texture,
                                      render_randomized, sample_randomization)
from laplab.sensors.texture import (BORDER, CENTER, FLOOR, ROAD, TextureParams, TexturePalette,
                                    build_track_texture, luma601)

TRACKS = Path(__file__).resolve().parents[2].parent / "shared" / "reference-tracks"
HALF_WIDTH = 0.3       # m: the synthetic straight road is 0.6 m wide, centred on y = 0
X_START, X_END = -2.0, 30.0
PLAIN = TexturePalette(grain=0.0)
TEXTURE = TextureParams(texel_size=0.01, margin=2.0, palette=PLAIN)
# A camera with round numbers for the hand derivations below; no mip levels so colours stay pure.
CAMERA = CameraParams(mount_forward=0.2, mount_up=0.1, pitch=math.radians(15.0), mipmap=False)


def straight_route(half_width=HALF_WIDTH, x_start=X_START, x_end=X_END, step=0.1):
    """Open (N, 6) strip along +x: centre y = 0, inner (left) border y = +half_width, outer y = -half_width."""
    x = np.arange(x_start, x_end + 1e-9, step)
    zero = np.zeros_like(x)
    return np.column_stack([x, zero, x, zero + half_width, x, zero - half_width])


@pytest.fixture(scope="module")
def straight_texture():
    return build_track_texture(straight_route(), TEXTURE)


def grey(colour):
    return int(luma601(np.array(colour)))


def focal(camera):
    """Focal length in pixels: half the image width over tan(half the horizontal field of view)."""
    return (camera.width / 2) / math.tan(camera.fov / 2)


def ray_length(camera, v):
    """Ray parameter t (forward component 1 in the camera frame) where image row v meets the ground."""
    up = -(v - camera.height / 2) / focal(camera)
    return camera.mount_up / (math.sin(camera.pitch) - math.cos(camera.pitch) * up)


def ground_hit(camera, u, v):
    """(forward, left) metres from the car origin where the ray through image point (u, v) meets the
    ground: the pinhole model written out by hand (v down, u right, pitch down)."""
    f = focal(camera)
    up, left = -(v - camera.height / 2) / f, -(u - camera.width / 2) / f
    cp, sp = math.cos(camera.pitch), math.sin(camera.pitch)
    dx, dz = cp + sp * up, -sp + cp * up
    t = camera.mount_up / -dz
    return camera.mount_forward + t * dx, camera.mount_lateral + t * left


def test_centred_car_sees_a_left_right_symmetric_road(straight_texture):
    frame = render_camera(straight_texture, [[0.0, 0.0, 0.0]], CAMERA)[0]
    first_row = int(math.ceil(CAMERA.horizon_row)) + 10  # these rows meet the floor well inside the room
    ground = frame[first_row:].astype(int)
    assert np.mean(ground != ground[:, ::-1]) < 0.002
    assert len(np.unique(ground)) >= 3  # road, border tape, floor (and centre dashes) are all visible


def test_border_tape_appears_at_the_columns_the_pinhole_model_predicts(straight_texture):
    frame = render_camera(straight_texture, [[0.0, 0.0, 0.0]], CAMERA)[0]
    row = 40
    lateral = np.array([ground_hit(CAMERA, col + 0.5, row + 0.5)[1] for col in range(CAMERA.width)])
    tape = HALF_WIDTH - TEXTURE.border_line_width
    margin = 0.012  # a texel plus a little: pixels this close to an edge may show either side
    expected = {grey(PLAIN.road): (abs(lateral) > 0.02 + margin) & (abs(lateral) < tape - margin),
                grey(PLAIN.border): (abs(lateral) > tape + margin) & (abs(lateral) < HALF_WIDTH - margin),
                grey(PLAIN.floor): abs(lateral) > HALF_WIDTH + margin}
    for value, columns in expected.items():
        assert columns.sum() >= 5
        assert np.all(frame[row, columns] == value), (value, np.flatnonzero(columns), frame[row, columns])
    left_tape = np.flatnonzero(frame[row, :80] == grey(PLAIN.border))
    f, t = focal(CAMERA), ray_length(CAMERA, row + 0.5)
    # Column of a lateral offset y: u = W/2 - y * f / t; the tape spans y in [0.25, 0.30].
    assert left_tape.min() == pytest.approx(80 - HALF_WIDTH * f / t, abs=1.0)
    assert left_tape.max() + 1 == pytest.approx(80 - tape * f / t, abs=1.0)


def test_pixel_whose_ray_hits_a_centre_dash_has_the_centre_line_grey(straight_texture):
    row = 60
    forward, _ = ground_hit(CAMERA, 80.0, row + 0.5)
    dash_centre = X_START + TEXTURE.dash_length / 2 + 10 * (TEXTURE.dash_length + TEXTURE.dash_gap)
    car_x = dash_centre - forward
    frame = render_camera(straight_texture, [[car_x, 0.0, 0.0]], CAMERA)[0]
    assert frame[row, 79] == frame[row, 80] == grey(PLAIN.center)
    # Half a period further on, the same pixels see the gap: plain road.
    gap = render_camera(straight_texture, [[car_x + 0.15, 0.0, 0.0]], CAMERA)[0]
    assert gap[row, 79] == gap[row, 80] == grey(PLAIN.road)


@pytest.mark.parametrize("pitch_deg", [15.0, 5.0])
def test_horizon_row_is_where_the_pitch_puts_it(pitch_deg):
    # A huge room with a 2 cm high wall: everything above the horizon is sky, everything below floor.
    params = TextureParams(texel_size=0.5, margin=300.0, wall_height=0.02, palette=PLAIN)
    texture = build_track_texture(straight_route(), params)
    camera = CAMERA.with_(pitch=math.radians(pitch_deg))
    horizon = camera.height / 2 - focal(camera) * math.tan(camera.pitch)
    assert camera.horizon_row == pytest.approx(horizon)
    frame = render_camera(texture, [[0.0, 0.0, 0.0]], camera)[0]
    above, below = int(math.floor(horizon - 0.5)), int(math.ceil(horizon + 0.5))
    assert np.all(frame[:above + 1] == grey(PLAIN.sky))
    assert np.all(frame[below:] != grey(PLAIN.sky))
    assert np.all(frame[below, :10] == grey(PLAIN.floor))  # far beside the road: the floor
    hits = camera_rays(camera).hits_ground.reshape(camera.height, camera.width)
    assert np.array_equal(hits[:, 0], np.arange(camera.height) + 0.5 > horizon)


def test_left_stereo_camera_sees_the_centre_line_shifted_right(straight_texture):
    row = 70
    forward, _ = ground_hit(CAMERA, 80.0, row + 0.5)
    car_x = X_START + TEXTURE.dash_length / 2 + 10 * (TEXTURE.dash_length + TEXTURE.dash_gap) - forward
    cameras = tuple(cam.with_(mount_forward=0.2, mount_up=0.1, mipmap=False) for cam in STEREO_CAMERAS)
    frames = render_cameras(straight_texture, [[car_x, 0.0, 0.0]], cameras)
    assert frames.shape == (1, 120, 160, 2)
    # The left camera sits at y = +0.03, so the centre line (y = 0) lies 0.03 m to its right:
    # 0.03 * f / t pixels right of the image centre; the right camera sees it as far to the left.
    shift = 0.03 * focal(CAMERA) / ray_length(CAMERA, row + 0.5)
    for channel, sign in ((0, +1), (1, -1)):
        dash = np.flatnonzero(frames[0, row, :, channel] == grey(PLAIN.center))
        assert (dash.min() + dash.max() + 1) / 2 == pytest.approx(80 + sign * shift, abs=1.0)


def render_camera_reference(texture, poses, params):
    """Plain-numpy implementation of render_camera (variant 0): the parity oracle of the numba kernel."""
    poses = np.asarray(poses, dtype=np.float64)
    variant = np.zeros(len(poses), dtype=np.int64)
    rays = camera_rays(params)
    level = sample_levels(params, texture.texel_size, texture.num_levels).astype(np.int64)[None, :]
    x, y, yaw = poses[:, 0:1], poses[:, 1:2], poses[:, 2:3]
    c, s = np.cos(yaw), np.sin(yaw)
    inv = 1.0 / texture.texel_size
    u0, v0 = ((x - texture.x0) * inv).astype(np.float32), ((y - texture.y0) * inv).astype(np.float32)
    a, b = (c * inv).astype(np.float32), (s * inv).astype(np.float32)
    tu = u0 + a * rays.ground_x - b * rays.ground_y
    tv = v0 + b * rays.ground_x + a * rays.ground_y
    on_tex = (level >= 0) & (tu > -1) & (tv > -1) & (tu < texture.width) & (tv < texture.height)
    safe_level = np.maximum(level, 0)
    ix = np.clip(tu, 0, texture.width - 1).astype(np.int64) >> safe_level
    iy = np.clip(tv, 0, texture.height - 1).astype(np.int64) >> safe_level
    tex_index = np.where(on_tex, texture.level_offset[safe_level] + iy * texture.level_width[safe_level] + ix, 0)
    # Walls: where the horizontal ray leaves the room rectangle (same formulas as _wall_index).
    cx = x + c * params.mount_forward - s * params.mount_lateral
    cy = y + s * params.mount_forward + c * params.mount_lateral
    wx, wy = c * rays.dir_x - s * rays.dir_y, s * rays.dir_x + c * rays.dir_y
    x_lo, y_lo, x_hi, y_hi = texture.room
    gap_x, gap_y = np.where(wx > 0, x_hi - cx, cx - x_lo), np.where(wy > 0, y_hi - cy, cy - y_lo)
    speed_x, speed_y = np.abs(wx) + 1e-12, np.abs(wy) + 1e-12
    hits_x_wall = gap_x * speed_y < gap_y * speed_x
    t = np.where(hits_x_wall, gap_x, gap_y) / np.where(hits_x_wall, speed_x, speed_y)
    px, py = cx + t * wx, cy + t * wy
    span_x, span_y = x_hi - x_lo, y_hi - y_lo
    p = np.where(hits_x_wall, np.where(wx > 0, span_x + (py - y_lo), 2 * span_x + span_y + (y_hi - py)),
                 np.where(wy > 0, span_x + span_y + (x_hi - px), px - x_lo))
    z = params.mount_up + rays.slope * t
    row = np.clip((z * (1.0 / texture.wall_texel_size)).astype(np.int64), 0, texture.wall_rows - 1)
    col = np.clip((p * (1.0 / texture.wall_texel_size)).astype(np.int64), 0, texture.wall_cols - 1)
    wall_index = np.where((z >= texture.wall_height) | (t < 0), texture.sky_index,
                          texture.wall_offset + row * texture.wall_cols + col)
    index = np.where(on_tex, tex_index, wall_index)
    # Bilinear: level-0 ground samples blend the 2x2 texels around (tu - 0.5, tv - 0.5).
    blend = params.bilinear & on_tex & (level == 0)
    su = np.clip(tu - np.float32(0.5), 0, texture.width - 1).astype(np.float32)
    sv = np.clip(tv - np.float32(0.5), 0, texture.height - 1).astype(np.float32)
    wu = np.where(blend, su - np.floor(su), 0).astype(np.float32)
    wv = np.where(blend, sv - np.floor(sv), 0).astype(np.float32)
    corner = np.where(blend, np.floor(sv).astype(np.int64) * texture.width + np.floor(su).astype(np.int64), index)
    k2 = params.supersample ** 2
    frames = []
    for plane in [texture.gray] if params.grayscale else list(texture.rgb):
        texel = lambda offset: plane[variant[:, None], np.minimum(corner + offset, plane.shape[1] - 1)].astype(np.float32)
        low = texel(0) + wu * (texel(1) - texel(0))
        high = texel(texture.width) + wu * (texel(texture.width + 1) - texel(texture.width))
        value = low + wv * (high - low)
        summed = value.reshape(-1, params.height, params.width, k2).sum(axis=3)
        if params.bilinear:
            frames.append((summed / k2 + 0.5).astype(np.uint8))
        else:
            frames.append(((summed.astype(np.int64) + k2 // 2) // k2).astype(np.uint8))
    return frames[0] if params.grayscale else np.stack(frames, axis=-1)


@pytest.fixture(scope="module")
def track_and_texture():
    path = TRACKS / "reinvent_base.npy"
    route = np.load(path) if path.is_file() else straight_route()
    return route, build_track_texture(route, TextureParams(texel_size=0.01))


@pytest.mark.parametrize("camera", [FRONT_FACING_CAMERA, FRONT_FACING_CAMERA.with_(supersample=2),
                                    LEFT_CAMERA.with_(mipmap=False, pitch=-0.2),
                                    CameraParams(width=96, height=72, grayscale=False, supersample=2),
                                    FRONT_FACING_CAMERA.with_(bilinear=True), HUMAN_CAMERA.with_(width=96, height=72)])
def test_numba_kernel_matches_numpy_reference(track_and_texture, camera):
    route, texture = track_and_texture
    rng = np.random.default_rng(3)
    x0, y0, x1, y1 = texture.room
    # Poses on the track, anywhere in the room, and a few outside it (looking at walls from behind).
    rows = rng.integers(0, len(route) - 1, 12)
    on_track = np.column_stack([route[rows, 0:2], rng.uniform(-np.pi, np.pi, 12)])
    anywhere = np.column_stack([rng.uniform(x0 - 1, x1 + 1, 12), rng.uniform(y0 - 1, y1 + 1, 12),
                                rng.uniform(-np.pi, np.pi, 12)])
    poses = np.vstack([on_track, anywhere])
    fast = render_camera(texture, poses, camera).astype(int)
    slow = render_camera_reference(texture, poses, camera).astype(int)
    assert fast.shape == slow.shape == (24, camera.height, camera.width) + (() if camera.grayscale else (3,))
    assert np.mean(np.abs(fast - slow) > 1) < 1e-3


def test_rendering_is_deterministic_and_writes_into_out(straight_texture):
    poses = np.array([[0.0, 0.0, 0.0], [3.0, 0.1, 0.2]])
    out = np.zeros((2, 120, 160), dtype=np.uint8)
    result = render_camera(straight_texture, poses, out=out)
    assert result is out
    assert np.array_equal(out, render_camera(straight_texture, poses))
    assert np.array_equal(render_camera(straight_texture, poses[1:]), out[1:])  # cars are independent


def test_texture_classes_at_known_points(straight_texture):
    tex = straight_texture
    def class_at(x, y):
        return tex.classes[int((y - tex.y0) / tex.texel_size), int((x - tex.x0) / tex.texel_size)]
    assert class_at(X_START + 0.075, 0.0) == CENTER          # middle of the first dash
    assert class_at(X_START + 0.225, 0.0) == ROAD            # middle of the first gap
    assert class_at(5.0, 0.15) == ROAD
    assert class_at(5.0, HALF_WIDTH - 0.025) == BORDER
    assert class_at(5.0, -(HALF_WIDTH - 0.025)) == BORDER
    assert class_at(5.0, HALF_WIDTH + 0.05) == FLOOR
    assert tex.gray.shape == (1, tex.sky_index + 1) and tex.rgb.shape == (3, 1, tex.sky_index + 1)
    assert tex.level_image(1).shape[:2] == ((tex.height + 1) // 2, (tex.width + 1) // 2)


def test_camera_for_sensor_names():
    assert camera_for_sensor("FRONT_FACING_CAMERA") == (FRONT_FACING_CAMERA,)
    assert camera_for_sensor("STEREO_CAMERAS") == STEREO_CAMERAS
    assert camera_for_sensor("LEFT_CAMERA") == (STEREO_CAMERAS[0],)
    assert STEREO_CAMERAS[0].mount_lateral - STEREO_CAMERAS[1].mount_lateral == pytest.approx(0.06)
    with pytest.raises(ValueError, match="known camera sensors"):
        camera_for_sensor("SECTOR_LIDAR")


def test_bad_input_gets_a_clear_error(straight_texture):
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        render_camera(straight_texture, np.zeros((2, 2)))
    with pytest.raises(ValueError, match="variant"):
        render_camera(straight_texture, np.zeros((1, 3)), variant=3)
    with pytest.raises(ValueError, match="fov"):
        CameraParams(fov=4.0)
    with pytest.raises(ValueError, match="out must be"):
        render_camera(straight_texture, np.zeros((1, 3)), out=np.zeros((1, 120, 161), np.uint8))


def test_randomisation_is_seeded_and_off_by_default(straight_texture):
    poses = np.array([[0.0, 0.0, 0.0], [4.0, -0.1, 0.1], [9.0, 0.1, -0.1]])
    plain = render_camera(straight_texture, poses)
    off = sample_randomization(np.random.default_rng(0), 3, RandomizationParams())
    assert np.array_equal(render_randomized(straight_texture, poses, FRONT_FACING_CAMERA, off,
                                            np.random.default_rng(0)), plain)

    on = RandomizationParams(enabled=True, texture_variants=2)
    def run(seed):
        rng = np.random.default_rng(seed)
        texture = build_randomized_texture(straight_route(), TEXTURE, on, rng)
        draw = sample_randomization(rng, 3, on, FRONT_FACING_CAMERA, texture.num_variants)
        return render_randomized(texture, poses, FRONT_FACING_CAMERA, draw, rng)
    first, again, other = run(7), run(7), run(8)
    assert np.array_equal(first, again)
    rng = np.random.default_rng(1)
    stereo = render_randomized(straight_texture, poses, STEREO_CAMERAS, sample_randomization(rng, 3, on), rng)
    assert stereo.shape == (3, 120, 160, 2)
    assert not np.array_equal(first, other)
    assert np.mean(np.abs(first.astype(int) - plain.astype(int))) > 2.0


def test_photometric_changes_do_what_they_say(straight_texture):
    frames = render_camera(straight_texture, [[0.0, 0.0, 0.0], [5.0, 0.1, 0.2]])
    identity = sample_randomization(np.random.default_rng(0), 2, RandomizationParams())
    brighter = apply_photometric(frames, identity._replace(brightness=np.array([12.0, -30.0])), np.random.default_rng(0))
    assert np.array_equal(brighter.astype(int), np.clip(frames.astype(int) + np.array([12, -30])[:, None, None], 0, 255))
    blurred = apply_photometric(frames, identity._replace(blur=np.ones(2)), np.random.default_rng(0)).astype(int)
    padded = np.pad(frames.astype(float), ((0, 0), (1, 1), (1, 1)), mode="edge")
    box = sum(padded[:, i:i + 120, j:j + 160] for i in range(3) for j in range(3)) / 9.0
    assert np.abs(blurred - np.rint(box)).max() <= 1
    shifted = apply_photometric(frames, identity._replace(row_shift=np.array([3, -2])), np.random.default_rng(0))
    assert np.array_equal(shifted[0, :-3], frames[0, 3:]) and np.array_equal(shifted[1, 2:], frames[1, :-2])
    noisy = apply_photometric(frames, identity._replace(noise=np.array([5.0, 0.0])), np.random.default_rng(0))
    assert 4.0 < np.std(noisy[0].astype(float) - frames[0]) < 6.0 and np.array_equal(noisy[1], frames[1])
