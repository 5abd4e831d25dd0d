"""A reward function in the 2018 DeepRacer signature, as in that year's tutorials.

laplab recognises this signature and calls it with positional arguments converted from the
modern params dict: ``on_track`` (all wheels on the track), ``car_orientation`` (heading, rad),
``progress`` in [0, 1], ``throttle`` = speed / max speed in [0, 1], ``steering`` = steering angle /
30 deg in [-1, 1], ``closest_waypoint`` (the nearer of the two closest waypoints); ``self`` is None.

It rewards staying near the centre line, pointing along the track, throttle, and not steering
harder than half lock.
"""

import math


def reward_function(self, on_track, x, y, distance_from_center, car_orientation, progress, steps,
                    throttle, steering, track_width, waypoints, closest_waypoint):
    """Centre-line bands, halved when heading 30+ deg off the track, scaled by throttle and steering."""
    if not on_track:
        return 1e-3

    marker_1 = 0.1 * track_width
    marker_2 = 0.25 * track_width
    marker_3 = 0.5 * track_width
    if distance_from_center <= marker_1:
        reward = 1.0
    elif distance_from_center <= marker_2:
        reward = 0.5
    elif distance_from_center <= marker_3:
        reward = 0.1
    else:
        return 1e-3

    # Track direction at the closest waypoint; a closed loop repeats its first point at the end.
    size = len(waypoints) - 1 if tuple(waypoints[0]) == tuple(waypoints[-1]) else len(waypoints)
    here = waypoints[closest_waypoint % size]
    ahead = waypoints[(closest_waypoint + 1) % size]
    track_direction = math.atan2(ahead[1] - here[1], ahead[0] - here[0])
    heading_error = abs((car_orientation - track_direction + math.pi) % (2 * math.pi) - math.pi)
    if heading_error > math.radians(30):
        reward *= 0.5

    if abs(steering) > 0.5:
        reward *= 0.8

    reward *= 0.5 + 0.5 * throttle
    return float(reward)
