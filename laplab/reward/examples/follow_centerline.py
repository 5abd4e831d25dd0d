"""Follow the centre line: the AWS DeepRacer console's default reward function.

Three markers at 10 %, 25 % and 50 % of the track width split the track into bands around the
centre line; the nearer the car's reference point is to the centre, the higher the reward.
It teaches a car to stay on the track quickly, but not to drive fast or to cut corners.
"""


def reward_function(params):
    """1.0 within 0.1 track widths of the centre line, 0.5 within 0.25, 0.1 within 0.5, else 1e-3."""
    track_width = params["track_width"]
    distance_from_center = params["distance_from_center"]

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
        reward = 1e-3  # past the border: about to leave the track

    return float(reward)
