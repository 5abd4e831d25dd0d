"""Reward the pace of the lap: progress per step, squared, plus a bonus for finishing the lap that
grows with its pace. laplab's default reward function.

A lap driven in fewer steps earns more on every step, so the policy learns to go fast; finishing
earns a bonus as large as the whole lap's pace reward, so a fast lap always beats a faster crash;
leaving the track earns almost nothing and ends the episode, so the policy learns where it cannot
go. A small share of the reward keeps the car near the centre line early in training.

Made for fast action spaces such as laplab's default (7 steering angles x 1.33, 2.67 and 4 m/s,
the console's largest grid); see BENCHMARKS.md for the lap times it reaches.
"""

PACE_WEIGHT = 1.0     # reward for a pace of 1 % of the lap per step
CENTRE_WEIGHT = 0.1   # share for staying near the centre line
FINISH_BONUS = 100.0  # x the lap's pace (% per step), paid on the step that completes the lap


def reward_function(params):
    """Pace of the lap so far (% of the lap per step) squared, a little for the centre, and a
    finishing bonus; ~0 with a wheel off the track."""
    if params['is_offtrack'] or not params['all_wheels_on_track']:
        return 1e-3
    steps = max(params['steps'], 1.0)
    pace = max(params['progress'], 0.0) / steps  # progress is negative behind the start line
    half_width = 0.5 * params['track_width']
    centre = 1.0 - min(params['distance_from_center'] / half_width, 1.0)
    reward = PACE_WEIGHT * pace ** 2 + CENTRE_WEIGHT * centre
    if params['progress'] >= 100.0:
        reward += FINISH_BONUS * pace
    return float(reward)
