"""The optimal lap time of a track, for "gap to optimal": the race line's lap time, from the race-line
cache shared with ``laplab raceline`` (``$LAPLAB_HOME/cache``), so evaluations and the leaderboard
do not solve the race line again."""

from laplab.track.raceline_cache import cache_folder as cache_dir
from laplab.track.raceline_cache import optimal_lap_time, standing_start_optimal_lap_time

__all__ = ["cache_dir", "optimal_lap_time", "standing_start_optimal_lap_time"]
