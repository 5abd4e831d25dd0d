"""Obstacles as the sensors see them: the camera draws solid lit boxes that hide what lies behind them,
the lidar's beams stop at them; a numpy reference checks the camera's numba pass; no obstacles leave
every frame and scan exactly as it was."""

import math

import numpy as np
import pytest

from laplab.sensors.camera import (FRONT_FACING_CAMERA, LEFT_CAMERA, CameraParams, camera_rays, render_camera,
                                   render_cameras)
from laplab.sensors.lidar import DEFAULT_LIDAR, LidarParams, LidarWalls, scan
from laplab.sensors.obstacle_look import (BACK, BOT_CAR, BOX, BOX_SIZE, CAR_SIZE, EMPTY, LEFT, MODEL_CAR, RIGHT,
                                          ObstacleLook, face_colours, obstacle_boxes)
from laplab.sensors.texture import build_track_texture
from tests.sensors import test_camera
from tests.sensors.test_camera import CAMERA, TEXTURE, render_camera_reference, straight_route

track_and_texture = test_camera.track_and_texture  # the fixture of test_camera.py, shared here

BOX_HALF = (BOX_SIZE[0] / 2, BOX_SIZE[1] / 2, BOX_SIZE[2])


def obstacles(rows):
    """Seven (N, K) arrays from rows[n] = list of (x, y, yaw, half_length, half_width, height, kind)."""
    k = max(len(r) for r in rows)
    table = np.zeros((len(rows), k, 7))
    for n, row in enumerate(rows):
        for q, item in enumerate(row):
            table[n, q] = item
    return tuple(table[..., i] for i in range(6)) + (table[..., 6].astype(np.int64),)


def box_at(x, y, yaw=0.0, kind=BOX, size=BOX_HALF):
    return (x, y, yaw) + tuple(size) + (kind,)


@pytest.fixture(scope="module")
def straight_texture():
    return build_track_texture(straight_route(), TEXTURE)


def project(camera, x, y, z):
    """(u, v) image point of the car-frame point (x forward, y left, z up), pinhole model by hand."""
    f = 0.5 * camera.width / math.tan(0.5 * camera.fov)
    x, y, z = x - camera.mount_forward, y - camera.mount_lateral, z - camera.mount_up
    cp, sp = math.cos(camera.pitch), math.sin(camera.pitch)
    depth = cp * x - sp * z
    return 0.5 * camera.width - f * y / depth, 0.5 * camera.height - f * (sp * x + cp * z) / depth


def test_kind_codes_and_fields_match_the_simulators_obstacles():
    from laplab.sim.obstacles import BOT_CAR as SIM_BOT, BOX as SIM_BOX, EMPTY as SIM_EMPTY
    from laplab.sim.obstacles import MODEL_CAR as SIM_MODEL, Obstacles, no_obstacles
    assert (EMPTY, BOX, BOT_CAR, MODEL_CAR) == (SIM_EMPTY, SIM_BOX, SIM_BOT, SIM_MODEL)
    assert Obstacles._fields == ("x", "y", "yaw", "half_length", "half_width", "height", "kind")
    assert obstacle_boxes(no_obstacles(3, 4), 3, "test") is None
    assert obstacle_boxes(Obstacles(*obstacles([[box_at(1.0, 0.0)]])), 1, "test").any


def test_no_obstacles_leave_the_frames_bit_exact(straight_texture, track_and_texture):
    from laplab.sim.obstacles import no_obstacles
    _, texture = track_and_texture
    poses = np.array([[0.0, 0.0, 0.0], [3.0, 0.1, 0.2], [1.0, 2.0, -2.0]])
    for tex in (straight_texture, texture):
        for camera in (FRONT_FACING_CAMERA, CameraParams(width=64, height=48, grayscale=False, supersample=2)):
            plain = render_camera(tex, poses, camera)
            assert np.array_equal(plain, render_camera(tex, poses, camera, obstacles=no_obstacles(3, 5)))
            assert np.array_equal(plain, render_camera(tex, poses, camera, obstacles=no_obstacles(3, 0)))
        stereo = render_cameras(tex, poses, (LEFT_CAMERA, FRONT_FACING_CAMERA))
        assert np.array_equal(stereo, render_cameras(tex, poses, (LEFT_CAMERA, FRONT_FACING_CAMERA),
                                                     obstacles=no_obstacles(3, 2)))


def test_face_colours_follow_gazebos_diffuse_shading_by_hand():
    # Gazebo's default sun only: 0.8 diffuse shining along (-0.5, 0.1, -0.9); scene ambient 0.5.
    colours = face_colours(obstacle_boxes(obstacles([[box_at(1.0, 0.0)]]), 1, "test"))[0, 0]
    brown = np.array([0.482, 0.38, 0.309])  # box_obstacle's ambient = diffuse
    towards_sun = np.array([0.5, -0.1, 0.9]) / math.sqrt(0.25 + 0.01 + 0.81)
    top = 0.5 * brown + brown * 0.8 * towards_sun[2]
    front = 0.5 * brown + brown * 0.8 * towards_sun[0]   # the +x face turns to the sun
    back = 0.5 * brown                                   # the -x face turns away: ambient only
    for face, rgb in ((4, top), (0, front), (BACK, back)):
        expected = np.rint(255 * rgb).astype(int)
        assert colours[face, :3].tolist() == expected.tolist()
        assert colours[face, 3] == (299 * expected[0] + 587 * expected[1] + 114 * expected[2] + 500) // 1000
    bot = face_colours(obstacle_boxes(obstacles([[box_at(1.0, 0.0, 0.0, BOT_CAR)]]), 1, "test"))[0, 0]
    assert bot[BACK, :3].tolist() == [round(255 * 0.5 * 0.156)] * 3  # the bot car's 0x28 grey shell


def test_camera_sees_a_box_in_front_in_its_lit_colour_hiding_the_road(straight_texture):
    pose = np.array([[0.0, 0.0, 0.0]])
    front = obstacles([[box_at(1.2, 0.0)]])
    plain = render_camera(straight_texture, pose, CAMERA)[0]
    seen = render_camera(straight_texture, pose, CAMERA, obstacles=front)[0]
    # The face towards the car is the box's back (-x) face, lit by the default sun.
    grey = face_colours(obstacle_boxes(front, 1, "test"))[0, 0, BACK, 3]
    near = 1.2 - BOX_HALF[0]
    u_left, v_bottom = project(CAMERA, near, BOX_HALF[1], 0.0)
    u_right, v_top = project(CAMERA, near, -BOX_HALF[1], BOX_SIZE[2])
    inside = seen[int(v_top) + 2:int(v_bottom) - 1, int(u_left) + 2:int(u_right) - 1]
    u_left = project(CAMERA, near, BOX_HALF[1], BOX_SIZE[2])[0]  # the face's top edge is the wider (pitch)
    assert inside.size > 200 and np.all(inside == grey)
    assert np.all(seen[int(v_bottom) + 2:] == plain[int(v_bottom) + 2:])   # the road in front of the box
    hidden = plain[int(v_top) + 2:int(v_bottom) - 1, int(u_left) + 2:int(u_right) - 1]
    assert np.mean(hidden != grey) > 0.9                                   # the road behind it is gone
    assert np.all(seen[:, :int(u_left) - 1] == plain[:, :int(u_left) - 1])  # nothing beside it changes


def test_camera_does_not_see_boxes_behind_it_beside_it_or_beyond_the_wall(straight_texture):
    pose = np.array([[5.0, 0.0, 0.0]])
    plain = render_camera(straight_texture, pose, CAMERA)
    behind = obstacles([[box_at(4.0, 0.0), box_at(5.0, 0.6), box_at(3.0, -0.4, 0.3, BOT_CAR)]])
    assert np.array_equal(render_camera(straight_texture, pose, CAMERA, obstacles=behind), plain)
    # Nor one beyond the room's wall (the room starts at x = -4 m).
    towards_wall = np.array([[-3.0, 0.0, math.pi]])
    beyond = obstacles([[box_at(-4.6, 0.0)]])
    assert straight_texture.room[0] == pytest.approx(-4.0)
    assert np.array_equal(render_camera(straight_texture, towards_wall, CAMERA, obstacles=beyond),
                          render_camera(straight_texture, towards_wall, CAMERA))


def test_a_box_seen_at_an_angle_shows_two_differently_lit_sides(straight_texture):
    # Looking along -x at a box turned 45 degrees: its front (+x) and right faces turn to the camera.
    pose = np.array([[10.0, 0.0, math.pi]])
    turned = obstacles([[box_at(8.8, 0.0, math.pi / 4)]])
    colours = face_colours(obstacle_boxes(turned, 1, "test"))[0, 0, :, 3]
    frame = render_camera(straight_texture, pose, CAMERA, obstacles=turned)[0]
    front, right = colours[0], colours[RIGHT]
    assert front != right
    assert (frame == front).sum() > 100 and (frame == right).sum() > 100
    assert (frame == colours[LEFT]).sum() < 5 or colours[LEFT] in (front, right)


def test_nearer_obstacle_hides_a_farther_one(straight_texture):
    pose = np.array([[0.0, 0.0, 0.0]])
    look = ObstacleLook(model_car_color="Orange")
    near_car = box_at(1.2, 0.0, 0.0, MODEL_CAR, (CAR_SIZE[0] / 2, CAR_SIZE[1] / 2, CAR_SIZE[2]))
    both = obstacles([[box_at(2.5, 0.0), near_car]])
    car_only = obstacles([[near_car]])
    frame = render_camera(straight_texture, pose, CAMERA, obstacles=both, obstacle_look=look)[0]
    car_grey = face_colours(obstacle_boxes(car_only, 1, "test"), look=look)[0, 0, BACK, 3]
    u, v = project(CAMERA, 1.2 - CAR_SIZE[0] / 2, 0.0, 0.1)
    assert frame[int(v), int(u)] == car_grey
    # From 0.12 m up, the box 1.3 m behind the car hides wholly behind it (taller and wider as it is);
    # moved 0.4 m to the left it shows beside the car.
    assert np.array_equal(frame, render_camera(straight_texture, pose, CAMERA, obstacles=car_only,
                                               obstacle_look=look)[0])
    aside = obstacles([[box_at(2.5, 0.4), near_car]])
    box_grey = face_colours(obstacle_boxes(aside, 1, "test"))[0, 0, BACK, 3]
    beside = render_camera(straight_texture, pose, CAMERA, obstacles=aside, obstacle_look=look)[0]
    assert (beside == box_grey).sum() > 20 and (frame == box_grey).sum() == 0


def paint_obstacles_reference(texture, poses, params, rows, look=ObstacleLook()):
    """Plain numpy: every sample against every obstacle (no bounding rectangles), on the numpy frames."""
    frames = render_camera_reference(texture, poses, params).astype(np.int64)
    packed = obstacle_boxes(rows, len(poses), "reference")
    colours = face_colours(packed, texture.params.wall_lights, look)
    rays = camera_rays(params)
    dx, dy, dz = (a.astype(np.float64) for a in (rays.dir_x, rays.dir_y, rays.slope))
    k2, h = params.supersample ** 2, params.mount_up
    planes = [3] if params.grayscale else [0, 1, 2]
    x_lo, y_lo, x_hi, y_hi = texture.room
    for n, (x, y, yaw) in enumerate(poses):
        c, s = math.cos(yaw), math.sin(yaw)
        cx = x + c * params.mount_forward - s * params.mount_lateral
        cy = y + s * params.mount_forward + c * params.mount_lateral
        best = np.full(dx.shape, np.inf)
        value = np.zeros(dx.shape + (len(planes),), dtype=np.int64)
        for q in range(packed.kind.shape[1]):
            if packed.kind[n, q] == EMPTY:
                continue
            bx, by, byaw, hl, hw, height = packed.boxes[n, q]
            cq, sq = math.cos(byaw), math.sin(byaw)
            px, py = cq * (cx - bx) + sq * (cy - by), -sq * (cx - bx) + cq * (cy - by)
            wx, wy = c * dx - s * dy, s * dx + c * dy
            lx, ly = cq * wx + sq * wy, -sq * wx + cq * wy
            with np.errstate(divide="ignore", invalid="ignore"):
                ax, bx_ = (-hl - px) / lx, (hl - px) / lx
                ay, by_ = (-hw - py) / ly, (hw - py) / ly
            tx0, tx1 = np.minimum(ax, bx_), np.maximum(ax, bx_)
            ty0, ty1 = np.minimum(ay, by_), np.maximum(ay, by_)
            t0, t1 = np.maximum(tx0, ty0), np.minimum(tx1, ty1)
            face = np.where(tx0 > ty0, np.where(lx < 0, 0, 1), np.where(ly < 0, 2, 3))
            z = h + dz * t0
            side = (t0 >= 0) & (t0 <= t1) & (z >= 0) & (z <= height)
            with np.errstate(divide="ignore", invalid="ignore"):
                t_top = (height - h) / dz
            top = (t0 >= 0) & (t0 <= t1) & (z > height) & (dz < 0) & (t_top <= t1)
            t = np.where(side, t0, np.where(top, t_top, np.inf))
            face = np.where(top, 4, face)
            nearer = t < best
            best = np.where(nearer, t, best)
            value = np.where(nearer[:, None], colours[n, q][face][:, planes].astype(np.int64), value)
        wx, wy = c * dx - s * dy, s * dx + c * dy
        gap_x, gap_y = np.where(wx > 0, x_hi - cx, cx - x_lo), np.where(wy > 0, y_hi - cy, cy - y_lo)
        wall = np.minimum(gap_x / (np.abs(wx) + 1e-12), gap_y / (np.abs(wy) + 1e-12))
        hit = (best < wall).reshape(params.height, params.width, k2)
        hits = hit.sum(axis=-1)
        total = np.where(hit[..., None], value.reshape(params.height, params.width, k2, -1), 0).sum(axis=2)
        base = frames[n][..., None] if params.grayscale else frames[n]
        blended = (total + (k2 - hits)[..., None] * base + k2 // 2) // k2
        painted = np.where((hits > 0)[..., None], blended, base)
        frames[n] = painted[..., 0] if params.grayscale else painted
    return frames.astype(np.uint8)


@pytest.mark.parametrize("camera", [FRONT_FACING_CAMERA, FRONT_FACING_CAMERA.with_(supersample=2),
                                    LEFT_CAMERA.with_(pitch=-0.2),
                                    CameraParams(width=96, height=72, grayscale=False, supersample=2)])
def test_numba_obstacle_pass_matches_numpy_reference(track_and_texture, camera):
    route, texture = track_and_texture
    rng = np.random.default_rng(5)
    rows = rng.integers(0, len(route) - 8, 10)
    step = route[rows + 1, :2] - route[rows, :2]
    yaw = np.arctan2(step[:, 1], step[:, 0])
    poses = np.column_stack([route[rows, :2], yaw])
    items = []
    for n in range(len(poses)):
        row = []
        for q in range(4):  # ahead on the road, beside it, behind, and some slots empty
            ahead, side = rng.uniform(-1.0, 3.0), rng.uniform(-0.6, 0.6)
            x = poses[n, 0] + ahead * math.cos(yaw[n]) - side * math.sin(yaw[n])
            y = poses[n, 1] + ahead * math.sin(yaw[n]) + side * math.cos(yaw[n])
            kind = rng.choice([EMPTY, BOX, BOT_CAR, MODEL_CAR])
            size = BOX_HALF if kind == BOX else (CAR_SIZE[0] / 2, CAR_SIZE[1] / 2, CAR_SIZE[2])
            row.append(box_at(x, y, rng.uniform(-np.pi, np.pi), kind, size))
        items.append(row)
    # Walls between camera and box: a camera outside the room looking in at a box inside, and one
    # inside looking out at a box beyond the wall (hidden), beside a box in front of the wall.
    x0, y0, x1, y1 = texture.room
    middle = 0.5 * (y0 + y1)
    poses = np.vstack([poses, [[x0 - 0.5, middle, 0.0], [x0 + 1.0, middle, math.pi]]])
    items += [[box_at(x0 + 0.6, middle), box_at(x0 + 1.2, middle + 0.3, 0.4, BOT_CAR)],
              [box_at(x0 - 0.4, middle), box_at(x0 + 0.4, middle + 0.4, 0.2)]]
    rows_ = obstacles(items)
    fast = render_camera(texture, poses, camera, obstacles=rows_).astype(int)
    slow = paint_obstacles_reference(texture, poses, camera, rows_).astype(int)
    plain = render_camera(texture, poses, camera).astype(int)
    assert np.mean(fast != plain) > 0.01  # the obstacles are in view
    # Exact but where the ground renderer and its numpy reference round a level apart (< 0.01%).
    assert np.abs(fast - slow).max() <= 1 and np.mean(fast != slow) < 1e-4


def test_lidar_beam_reads_the_distance_to_a_box_in_front_and_ignores_one_behind():
    walls = LidarWalls.from_track(straight_route())
    pose = np.array([[0.0, 0.0, 0.0]])
    plain = scan(walls, pose)[0]
    box = obstacles([[box_at(2.0, 0.0)]])
    ranges = scan(walls, pose, obstacles=box)[0]
    angles = DEFAULT_LIDAR.beam_angles
    face = 2.0 - BOX_HALF[0] - DEFAULT_LIDAR.mount_x  # the box's near face, from the lidar
    for b in np.flatnonzero(np.abs(np.tan(angles) * face) < BOX_HALF[1] - 1e-6):
        expected = face / math.cos(angles[b])
        assert angles[b] != 0 and abs(angles[b]) < 0.2
        assert ranges[b] == pytest.approx(min(expected, plain[b]), abs=1e-5)
        assert ranges[b] < plain[b]
    far_off = np.abs(angles) > 0.3
    assert np.array_equal(ranges[far_off], plain[far_off])
    # A box behind the car changes no forward beam.
    behind = obstacles([[box_at(-1.5, 0.0), box_at(-0.8, 1.2, 0.5, BOT_CAR)]])
    back = scan(walls, pose, obstacles=behind)[0]
    forward = np.abs(angles) < math.pi / 2
    assert np.array_equal(back[forward], plain[forward])


def test_lidar_sees_a_bot_car_beside_it_at_the_closed_form_distance():
    walls = LidarWalls.from_segments(np.array([[50.0, -50.0, 50.0, 50.0]]))
    params = LidarParams(num_beams=3, min_angle=math.pi / 2 - 0.1, max_angle=math.pi / 2 + 0.1, noise_std=0.0)
    car = obstacles([[box_at(0.1, 1.0, 0.3, BOT_CAR, (CAR_SIZE[0] / 2, CAR_SIZE[1] / 2, CAR_SIZE[2]))]])
    ranges = scan(walls, np.array([[0.0, 0.0, 0.0]]), params, obstacles=car)[0]
    # The middle beam points straight left from (0.1, 0): the car's right side, turned 0.3 rad.
    half_w, c = CAR_SIZE[1] / 2, math.cos(0.3)
    assert ranges[1] == pytest.approx(1.0 - half_w / c, abs=1e-5)


def test_bad_obstacles_are_refused_with_a_clear_message(straight_texture):
    pose = np.zeros((2, 3))
    with pytest.raises(ValueError, match="N = 2 cars"):
        render_camera(straight_texture, pose, obstacles=obstacles([[box_at(1.0, 0.0)]]))
    bad = obstacles([[box_at(1.0, 0.0, 0.0, BOX, (0.2, -0.1, 0.25))], [box_at(1.0, 0.0)]])
    with pytest.raises(ValueError, match="positive half_length"):
        scan(LidarWalls.from_track(straight_route()), pose, obstacles=bad)
    with pytest.raises(ValueError, match="seven"):
        render_camera(straight_texture, pose, obstacles=(np.zeros((2, 1)),) * 3)


def test_randomised_frames_show_the_obstacles_too(straight_texture):
    from laplab.sensors.randomize import RandomizationParams, render_randomized, sample_randomization
    pose = np.array([[0.0, 0.0, 0.0]])
    front = obstacles([[box_at(1.2, 0.0)]])
    rng = np.random.default_rng(0)
    identity = sample_randomization(rng, 1, RandomizationParams(enabled=False), CAMERA)
    assert np.array_equal(render_randomized(straight_texture, pose, CAMERA, identity, rng, obstacles=front),
                          render_camera(straight_texture, pose, CAMERA, obstacles=front))
    jittered = sample_randomization(rng, 1, RandomizationParams(enabled=True, noise=0.0, blur=0.0), CAMERA)
    with_box = render_randomized(straight_texture, pose, CAMERA, jittered, np.random.default_rng(1), obstacles=front)
    without = render_randomized(straight_texture, pose, CAMERA, jittered, np.random.default_rng(1))
    assert np.mean(with_box != without) > 0.05
