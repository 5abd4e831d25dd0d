"""Greedy evaluation laps on every training track of a multi-track job (in the learner's process).

After each iteration DeepRacer evaluates the policy; a multi-track job (deepracer-for-cloud's
``DR_TRAIN_MULTI_CONFIG``) evaluates it on each of its tracks. :class:`MultiTrackEvaluator` runs
``eval_episodes`` laps per track from starts spread evenly over the lap and returns them as one
batch whose episodes are tagged with their track (the checkpoint metric is the mean over all).
"""

from __future__ import annotations

import numpy as np

from laplab.cluster.batches import TaggedEpisodeBatch, merge_batches, tag


def track_label(track: str, reverse: bool) -> str:
    return f"{track}@reversed" if reverse else track


class MultiTrackEvaluator:
    """``evaluate(policy)`` on every ``(track, reverse)`` of ``tracks`` with ``reward_fn``."""

    def __init__(self, config, reward_fn, tracks: list[tuple[str, bool]]):
        from laplab.env.observations import ObservationBuilder
        from laplab.env.step import EpisodeStepper
        from laplab.sim.simulator import Simulator
        from laplab.sim.state import EpisodeParams
        from laplab.track.registry import load_track
        from laplab.vehicle.params import vehicle_preset

        self.config = config
        self.tracks = list(tracks)
        vehicle = vehicle_preset(config.car)
        self.parts = []
        for number, (name, reverse) in enumerate(self.tracks):
            sim = Simulator(load_track(name), config.eval_episodes, vehicle,
                            EpisodeParams(round_robin_advance=0.0, reverse=reverse), race=config.race_type,
                            seed=config.seed + 1 + number)
            observations = ObservationBuilder(sim, config.spec, seed=config.seed + 1 + number)
            self.parts.append((track_label(name, reverse), EpisodeStepper(sim, config.spec.action_space, reward_fn),
                               observations))

    def evaluate(self, policy) -> TaggedEpisodeBatch:
        from laplab.train.collect import collect_episodes
        starts = np.arange(self.config.eval_episodes) / self.config.eval_episodes
        pieces = [tag(collect_episodes(stepper, observations, policy, keep_observations=False, ndist=starts),
                      number, label, -1)
                  for number, (label, stepper, observations) in enumerate(self.parts)]
        return merge_batches(pieces)

