"""DeepRacer evaluation: trials with lap times, penalties and resets; summaries; the leaderboard.

See docs/evaluation.md for the rules and the files written.
"""

from laplab.evaluate.summary import (
    INCIDENTS,
    EvaluationSummary,
    TrialResult,
    best_consecutive_average,
    gap_to_optimal,
    summarize,
)
from laplab.evaluate.trials import (
    CONSOLE_MAX_TRIALS,
    EvaluationError,
    EvaluationResult,
    EvaluationSettings,
    evaluate_model,
    evaluate_policy,
    read_evaluation_summary,
    save_evaluation,
)

__all__ = [
    "CONSOLE_MAX_TRIALS", "INCIDENTS", "EvaluationError", "EvaluationResult", "EvaluationSettings",
    "EvaluationSummary", "TrialResult", "best_consecutive_average", "evaluate_model", "evaluate_policy",
    "gap_to_optimal", "read_evaluation_summary", "save_evaluation", "summarize",
]
