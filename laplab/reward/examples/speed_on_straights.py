"""Go fast on straights, slow down for corners, detected from the waypoints ahead.

The track direction is measured along the centre line from the car's next waypoint to
LOOKAHEAD_M metres ahead. If it turns by less than STRAIGHT_TURN_DEG the car is on a straight and
is rewarded for speed; otherwise it is rewarded for a speed near CORNER_SPEED. A small share of
the reward keeps it near the centre line, and leaving the track earns almost nothing.
"""

import math

LOOKAHEAD_M = 2.0        # m of centre line examined ahead of the car
STRAIGHT_TURN_DEG = 10.0  # largest direction change, deg, that still counts as a straight
MAX_SPEED = 4.0          # m/s, the top of DeepRacer's action space
CORNER_SPEED = 2.0       # m/s aimed for when a corner is ahead


def _loop_size(waypoints):
    """Number of distinct waypoints: a closed loop repeats its first point at the end."""
    if len(waypoints) > 1 and tuple(waypoints[0]) == tuple(waypoints[-1]):
        return len(waypoints) - 1
    return len(waypoints)


def _segment_direction(waypoints, index, size):
    """Direction, rad, of the centre-line segment starting at waypoint ``index``."""
    x0, y0 = waypoints[index % size][:2]
    x1, y1 = waypoints[(index + 1) % size][:2]
    return math.atan2(y1 - y0, x1 - x0)


def max_turn_ahead(waypoints, start_index, lookahead_m=LOOKAHEAD_M):
    """Largest direction change, deg, of the centre line within ``lookahead_m`` after ``start_index``."""
    size = _loop_size(waypoints)
    start_direction = _segment_direction(waypoints, start_index, size)
    travelled = 0.0
    largest = 0.0
    index = start_index
    for _ in range(size):
        x0, y0 = waypoints[index % size][:2]
        x1, y1 = waypoints[(index + 1) % size][:2]
        segment = math.hypot(x1 - x0, y1 - y0)
        if segment > 0.0:
            turn = math.degrees(_segment_direction(waypoints, index, size) - start_direction)
            turn = abs((turn + 180.0) % 360.0 - 180.0)
            largest = max(largest, turn)
        travelled += segment
        if travelled >= lookahead_m:
            break
        index += 1
    return largest


def reward_function(params):
    """Speed reward (fast on straights, CORNER_SPEED in corners) plus a little centre-line reward."""
    if not params["all_wheels_on_track"] or params.get("is_offtrack", False):
        return 1e-3

    waypoints = params["waypoints"]
    next_index = params["closest_waypoints"][1]
    speed = params["speed"]

    on_straight = max_turn_ahead(waypoints, next_index) < STRAIGHT_TURN_DEG
    if on_straight:
        speed_score = speed / MAX_SPEED
    else:
        speed_score = max(0.0, 1.0 - abs(speed - CORNER_SPEED) / CORNER_SPEED)

    half_width = 0.5 * params["track_width"]
    centre_score = max(0.0, 1.0 - params["distance_from_center"] / half_width)

    return float(max(1e-3, 0.7 * speed_score + 0.3 * centre_score))
