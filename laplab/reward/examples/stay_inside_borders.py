"""Stay inside the two borders: the DeepRacer console's second example.

Every step with all four wheels on the track and at least 5 cm between the reference point and
the border earns the same reward; anything else earns almost nothing. The car is free to choose
its own line, which lets it learn to cut corners, at the price of slower early training.
"""

BORDER_MARGIN = 0.05  # m kept between the reference point and the border


def reward_function(params):
    """1.0 while all wheels are on the track and the car keeps BORDER_MARGIN from the border, else 1e-3."""
    all_wheels_on_track = params["all_wheels_on_track"]
    distance_from_center = params["distance_from_center"]
    track_width = params["track_width"]

    reward = 1e-3
    if all_wheels_on_track and (0.5 * track_width - distance_from_center) >= BORDER_MARGIN:
        reward = 1.0

    return float(reward)
