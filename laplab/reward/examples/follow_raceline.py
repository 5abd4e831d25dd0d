"""Follow a corner-cutting race line computed from the track's own waypoints, and go fast.

On the first call for a track, a race line is computed from the centre line in
``params['waypoints']`` with the curvature-smoothing idea of Remi Coulom's K1999 racer: every
point slides along the track's normal until the line's curvature there equals the mean of its
neighbours' curvatures, never further than MAX_OFFSET_FRACTION of the track width from the centre
line. Repeated over the whole loop, first with long then with short spans (STENCIL_STEPS), this
spreads each corner over a longer arc: the line enters wide, touches the inside at the apex and
exits wide, and it is shorter and less curved than the centre line. The line is cached per track
in a module global, so later steps only measure the car's distance to it (a few segments around
``closest_waypoints``). The reward grows as the car gets closer to the line and as it goes faster.

Self-contained: it uses only ``math`` and runs unchanged on AWS DeepRacer. The first call takes
about 0.1-0.3 s; every later call takes a few microseconds.
"""

import math

STENCIL_STEPS = (16, 8, 4, 2, 1)  # spans, in waypoints, of the curvature estimate; long first
PASSES_PER_STEP = 60              # sweeps over the loop at each span
MAX_OFFSET_FRACTION = 0.35        # of the track width: keeps the car body inside the borders
MAX_MOVE_PER_PASS = 0.05          # m a point may slide in one sweep (keeps the iteration stable)
MAX_SPEED = 4.0                   # m/s, the top of DeepRacer's action space

_RACELINES = {}  # track key -> race line, one (x, y) per entry of params['waypoints']


def _curvature(a, b, c):
    """Signed curvature, 1/m, of the circle through points a, b, c (positive = turning left)."""
    abx, aby = b[0] - a[0], b[1] - a[1]
    bcx, bcy = c[0] - b[0], c[1] - b[1]
    denominator = math.hypot(abx, aby) * math.hypot(bcx, bcy) * math.hypot(c[0] - a[0], c[1] - a[1])
    return 0.0 if denominator == 0.0 else 2.0 * (abx * bcy - aby * bcx) / denominator


def compute_raceline(waypoints, track_width):
    """Race line for ``waypoints`` (list of (x, y), m): one (x, y) per waypoint, same order."""
    points = [(float(p[0]), float(p[1])) for p in waypoints]
    # Distinct points only: a closed loop repeats its first point, some tracks repeat others too.
    distinct = [i for i in range(len(points)) if points[i] != points[i - 1]] or [0]
    centre = [points[i] for i in distinct]
    size = len(centre)
    normals = []
    for i in range(size):
        (px, py), (nx, ny) = centre[i - 1], centre[(i + 1) % size]
        length = math.hypot(nx - px, ny - py) or 1.0
        normals.append((-(ny - py) / length, (nx - px) / length))  # left of the driving direction

    max_offset = MAX_OFFSET_FRACTION * track_width
    offsets = [0.0] * size
    line = list(centre)

    def shifted(i, offset):
        return (centre[i][0] + offset * normals[i][0], centre[i][1] + offset * normals[i][1])

    for step in STENCIL_STEPS:
        if step > size // 8:
            continue
        for _ in range(PASSES_PER_STEP):
            for i in range(size):
                before, after = line[i - step], line[(i + step) % size]
                target = 0.5 * (_curvature(line[i - 2 * step], before, line[i])
                                + _curvature(line[i], after, line[(i + 2 * step) % size]))
                offset = offsets[i]
                here = _curvature(before, shifted(i, offset), after)
                slope = (_curvature(before, shifted(i, offset + 1e-3), after) - here) / 1e-3
                if slope == 0.0:
                    continue
                move = max(-MAX_MOVE_PER_PASS, min(MAX_MOVE_PER_PASS, (target - here) / slope))
                offsets[i] = max(-max_offset, min(max_offset, offset + move))
                line[i] = shifted(i, offsets[i])

    # Back to one point per waypoint: a repeated waypoint takes the point of its first copy.
    result = []
    position = 0
    for i in range(len(points)):
        if position + 1 < size and distinct[position + 1] == i:
            position += 1
        result.append(line[position] if i >= distinct[0] else line[-1])
    return result


def _track_key(waypoints):
    """Identifies a track (and its direction) by its waypoint count and two of its points."""
    middle = waypoints[len(waypoints) // 2]
    return (len(waypoints), round(waypoints[0][0], 3), round(waypoints[0][1], 3),
            round(waypoints[1][0], 3), round(middle[0], 3), round(middle[1], 3))


def raceline_for(waypoints, track_width):
    """The cached race line of this track (computed on first use with this step's width)."""
    key = _track_key(waypoints)
    if key not in _RACELINES:
        _RACELINES[key] = compute_raceline(waypoints, track_width)
    return _RACELINES[key]


def _distance_to_segment(x, y, a, b):
    ax, ay = a
    bx, by = b
    dx, dy = bx - ax, by - ay
    length_sq = dx * dx + dy * dy
    t = 0.0 if length_sq == 0.0 else max(0.0, min(1.0, ((x - ax) * dx + (y - ay) * dy) / length_sq))
    return math.hypot(x - (ax + t * dx), y - (ay + t * dy))


def distance_to_raceline(x, y, line, closest_waypoints):
    """Distance, m, from (x, y) to the race line, searched a few segments around the car."""
    size = len(line)
    previous_index, next_index = closest_waypoints
    return min(_distance_to_segment(x, y, line[i % size], line[(i + 1) % size])
               for i in range(previous_index - 3, next_index + 3))


def reward_function(params):
    """closeness**2 + 0.5 * closeness * speed / MAX_SPEED, closeness = 1 - distance / half width."""
    if not params["all_wheels_on_track"] or params.get("is_offtrack", False):
        return 1e-3

    track_width = params["track_width"]
    line = raceline_for(params["waypoints"], track_width)
    distance = distance_to_raceline(params["x"], params["y"], line, params["closest_waypoints"])
    closeness = max(0.0, 1.0 - distance / (0.5 * track_width))
    speed_score = params["speed"] / MAX_SPEED

    return float(max(1e-3, closeness ** 2 + 0.5 * closeness * speed_score))
