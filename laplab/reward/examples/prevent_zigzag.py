"""Follow the centre line without zig-zagging: the DeepRacer console's third example.

The centre-line bands of ``follow_centerline`` are kept, and steps that steer harder than
15 degrees either way lose 20 % of their reward, so the car learns smooth steering.
"""

ABS_STEERING_THRESHOLD = 15.0  # deg; DeepRacer's steering_angle is in degrees, positive = left


def reward_function(params):
    """Centre-line bands (1.0 / 0.5 / 0.1 / 1e-3), times 0.8 when |steering_angle| exceeds 15 deg."""
    distance_from_center = params["distance_from_center"]
    track_width = params["track_width"]
    abs_steering = abs(params["steering_angle"])

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
        reward = 1e-3

    if abs_steering > ABS_STEERING_THRESHOLD:
        reward *= 0.8

    return float(reward)
