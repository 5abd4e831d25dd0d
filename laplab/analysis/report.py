"""One HTML page (plus PNGs) about a model: training curves, trajectories, action usage, reward map,
evaluations over the race line, and evaluation videos.

The page is a self-contained folder (``<model>/report/`` by default): ``index.html`` links only files
beside it, needs no network and no JavaScript. Sections whose data do not exist yet say so instead of
failing, so a report can be built at any point of a model's life.
"""

from __future__ import annotations

import html
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from laplab.analysis.evaluations import Evaluation, load_evaluations
from laplab.analysis.loaders import (ReportDataError, TrainingHistory, last_episodes, load_training_history,
                                     load_training_traces, select_rows, traced_iterations)
from laplab.analysis.plots import (PlotStyle, iteration_range_text, plot_action_usage, plot_evaluation,
                                   plot_losses, plot_reward_map, reward_map_cell, plot_training, plot_trajectories)
from laplab.store.atomic import atomic_write_text, read_json
from laplab.store.layout import ModelFolder
from laplab.track.geometry import Track
from laplab.vehicle.physics import car_of_config

INDEX_NAME = "index.html"


@dataclass(frozen=True)
class ReportSettings:
    """recent_iterations: iterations whose episodes are drawn on the track; trajectory_episodes: at
    most this many of their (latest) episodes; usage_iterations: last iterations counted by the
    action-usage histogram and the reward map; max_evaluations: newest evaluations shown."""

    recent_iterations: int = 3
    trajectory_episodes: int = 30
    usage_iterations: int = 10
    max_evaluations: int = 6
    style: PlotStyle = field(default_factory=PlotStyle)


@dataclass(frozen=True)
class ReportContext:
    """What the sections share: the folder, its configuration, and where the report goes."""

    folder: ModelFolder
    out_dir: Path
    config: dict[str, Any]
    metadata: dict[str, Any]
    track: Track | None
    track_problem: str | None
    settings: ReportSettings


def _read_optional(path: Path) -> dict[str, Any]:
    try:
        document = read_json(path)
    except FileNotFoundError:
        return {}
    except ValueError as exc:
        raise ReportDataError(f"{path}: not valid JSON ({exc})") from None
    return document if isinstance(document, dict) else {}


def _load_track(name: str | None, reverse: bool) -> tuple[Track | None, str | None]:
    from laplab.track.geometry import TrackError
    from laplab.track.registry import load_track
    if not name:
        return None, ("the model folder names no track (laplab.json lacks 'track'); "
                      "`laplab report MODEL --track NAME` draws on the track you name")
    try:
        return load_track(name, reverse=reverse), None
    except (TrackError, FileNotFoundError, ValueError) as exc:
        return None, f"track {name!r} could not be loaded: {exc}"


def build_report(folder: ModelFolder, out_dir: str | Path | None = None, track: str | None = None,
                 settings: ReportSettings = ReportSettings()) -> Path:
    """Write the report of the model in ``folder`` to ``out_dir`` (default ``<model>/report``) and
    return the path of its ``index.html``. ``track`` overrides the model's training track."""
    if not folder.exists():
        raise ReportDataError(f"no model folder at {folder.root}")
    config = _read_optional(folder.laplab_config)
    metadata = _read_optional(folder.model_metadata) or config.get("model_metadata") or {}
    # An override names its own direction ("name@reversed"); the model's track runs as trained.
    reverse = False if track else bool(config.get("reverse", False))
    loaded_track, problem = _load_track(track or config.get("track"), reverse)
    out = Path(out_dir) if out_dir is not None else folder.root / "report"
    out.mkdir(parents=True, exist_ok=True)
    context = ReportContext(folder, out, config, metadata, loaded_track, problem, settings)
    history = load_training_history(folder)
    body = [_header(context, history), _training_section(context, history)]
    body += _track_sections(context)
    body.append(_evaluations_section(context))
    page = _page(f"laplab report: {folder.name}", "\n".join(body))
    index = atomic_write_text(out / INDEX_NAME, page)
    index.chmod(0o644)  # a page to share, like the PNGs beside it
    return index


# ------------------------------------------------------------------------------------ sections


def _esc(value: Any) -> str:
    return html.escape(str(value), quote=True)


def _figure(name: str, caption: str) -> str:
    return (f'<figure><img src="{_esc(name)}" alt="{_esc(caption)}">'
            f"<figcaption>{_esc(caption)}</figcaption></figure>")


def _note(text: str) -> str:
    return f'<p class="note">{_esc(text)}</p>'


def _table(headers: list[str], rows: list[list[Any]]) -> str:
    head = "".join(f"<th>{_esc(h)}</th>" for h in headers)
    body = "".join("<tr>" + "".join(f"<td>{_esc(c)}</td>" for c in row) + "</tr>" for row in rows)
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def _fmt(value: Any, digits: int = 2, unit: str = "") -> str:
    if value is None or (isinstance(value, float) and not np.isfinite(value)):
        return "–"
    if isinstance(value, float):
        return f"{value:.{digits}f}{unit}"
    return f"{value}{unit}"


def _header(context: ReportContext, history: TrainingHistory) -> str:
    folder, config, metadata = context.folder, context.config, context.metadata
    iterations_log = folder.metrics_dir / "laplab-iterations.json"
    last = (_read_optional(iterations_log).get("iterations") or [{}])[-1] if iterations_log.is_file() else {}
    best = _read_optional(folder.deepracer_checkpoints).get("best_checkpoint") or {}
    actions = metadata.get("action_space")
    action_text = (f"{len(actions)} discrete actions" if isinstance(actions, list)
                   else f"continuous {metadata.get('action_space_type', '')}".strip())
    track_text = (context.track.name if context.track is not None
                  else str(config.get("track", "?")) + (" (reversed)" if config.get("reverse") else ""))
    facts = [
        ("track", track_text),
        ("algorithm", metadata.get("training_algorithm", "?")),
        ("action space", action_text),
        ("sensors", ", ".join(metadata.get("sensor", [])) or "?"),
        ("network", network_text(metadata)),
        ("iterations", history.size),
        ("training episodes", int(history.episodes.training.sum()) if history.episodes is not None else last.get("episodes", "–")),
        ("environment steps", _fmt(last.get("env_steps"))),
        ("best lap", _fmt(last.get("best_lap_time"), 3, " s")),
        ("best checkpoint", best.get("name", "–")),
    ]
    if config.get("cloned_from"):
        facts.insert(1, ("cloned from", config["cloned_from"]))
    rows = "".join(f"<tr><th>{_esc(k)}</th><td>{_esc(v)}</td></tr>" for k, v in facts)
    error = folder.read_error()
    error_html = (f'<div class="error"><b>Training stopped with an error:</b><pre>{_esc(error)}</pre></div>'
                  if error else "")
    stamp = time.strftime("%Y-%m-%d %H:%M:%S")
    return (f"<header><h1>{_esc(folder.name)}</h1><p class='sub'>laplab report, {stamp} · "
            f"{_esc(folder.root)}</p></header>{error_html}<table class='facts'>{rows}</table>")


CAMERA_NAMES = ("FRONT_FACING_CAMERA", "STEREO_CAMERAS", "LEFT_CAMERA", "observation")


def network_text(metadata: dict) -> str:
    """The network as it is built: ``neural_network`` names conv layers that only a camera uses, so a
    model without a camera (STATE, lidar) has an MLP whatever the metadata names."""
    name = metadata.get("neural_network", "?")
    sensors = metadata.get("sensor") or []
    if any(sensor in CAMERA_NAMES for sensor in sensors):
        return name
    return f"MLP (dense layers on {', '.join(sensors) or 'the vector sensors'}; no camera, so no {name} convolutions)"


def losses_caption(algorithm: str | None) -> str:
    """What the learner-statistics panels show, for the model's algorithm."""
    lead = "Learner statistics per iteration (red: moving average). "
    if algorithm == "sac":
        return lead + ("SAC: critic loss is the twin Q networks' squared soft Bellman error, actor loss "
                       "alpha x log pi - Q (falls as the policy finds better actions), entropy -log pi of the "
                       "sampled actions, q mean the critic's value estimate.")
    return lead + "PPO: entropy falls as the policy grows sure; approx_kl is how far each update moved it."


def _training_section(context: ReportContext, history: TrainingHistory) -> str:
    parts = ["<section><h2>Training</h2>"]
    if history.size == 0:
        parts.append(_note("No training iteration has been logged yet."))
        return "".join(parts) + "</section>"
    style = context.settings.style
    plot_training(history, context.out_dir / "training.png", style)
    parts.append(_figure("training.png", "Per iteration: mean total reward and progress of the training episodes "
                         "(grey dots: single episodes; red: trailing moving average), lap-completion rate, and the greedy evaluation laps run after each iteration."))
    if history.losses:
        plot_losses(history, context.out_dir / "losses.png", style)
        parts.append(_figure("losses.png", losses_caption(context.metadata.get("training_algorithm"))))
    else:
        parts.append(_note("No learner statistics (metrics/laplab-iterations.json is absent)."))
    return "".join(parts) + "</section>"


def _section(title: str, content: str) -> str:
    return f"<section><h2>{_esc(title)}</h2>{content}</section>"


def _track_sections(context: ReportContext) -> list[str]:
    """Trajectories, action usage and the reward map, from the training simtrace."""
    settings, folder, out, track = context.settings, context.folder, context.out_dir, context.track
    titles = ("Trajectories", "Action usage", "Reward by track position")
    iterations = traced_iterations(folder)
    if not iterations:
        return [_section(title, _note("No training simtrace yet.")) for title in titles]
    usage_iterations = iterations[-settings.usage_iterations:]
    usage_text = iteration_range_text(usage_iterations)
    trace = load_training_traces(folder, usage_iterations)
    no_track = _note(context.track_problem or "no track")

    trajectories = reward_map = no_track
    if track is not None:
        recent_iterations = iterations[-settings.recent_iterations:]
        recent = last_episodes(select_rows(trace, np.isin(trace.iteration, recent_iterations)),
                               settings.trajectory_episodes)
        episodes = len(np.unique(recent.iteration * 10**9 + recent.episode))
        title = f"{episodes} training episodes of {iteration_range_text(recent_iterations)}, coloured by speed"
        plot_trajectories(track, recent, out / "trajectories.png", title, settings.style)
        trajectories = _figure("trajectories.png", f"{title}. Red crosses: where an episode left the track "
                               "(or crashed).")
        plot_reward_map(track, trace, out / "reward_map.png", f"mean step reward, training {usage_text}",
                        settings.style)
        reward_map = _figure("reward_map.png", "Mean reward your reward function gave per step, by position "
                             f"({reward_map_cell(track, settings.style):.2f} m cells, training {usage_text}).")
    kind = context.metadata.get("action_space_type", "discrete")
    plot_action_usage(trace, context.metadata.get("action_space", []), kind, out / "actions.png",
                      f"actions taken in training {usage_text} ({trace.size} steps)", settings.style)
    usage = _figure("actions.png", f"How often each action was taken during training {usage_text}."
                    if kind == "discrete" else
                    f"Steering angle x speed of the actions taken during training {usage_text}.")
    return [_section(titles[0], trajectories), _section(titles[1], usage), _section(titles[2], reward_map)]


# --------------------------------------------------------------------------------- evaluations


def _raceline(track: Track, vehicle_name: str):
    """The race line drawn under the trials (the quick solve: the picture needs no more)."""
    from laplab.track.raceline import FAST_SETTINGS, compute_raceline_for_track
    from laplab.vehicle.params import vehicle_preset
    return compute_raceline_for_track(track, vehicle_preset(vehicle_name), settings=FAST_SETTINGS)


def _optimal_lap_time(evaluation: Evaluation, track: Track | None, vehicle_name: str, line) -> float | None:
    """The optimal lap time the gaps are taken to: the evaluator's, else laplab evaluate's cached
    figure for this track, else the drawn race line's."""
    if evaluation.optimal_lap_time is not None or track is None:
        return evaluation.optimal_lap_time
    try:
        from laplab.evaluate.optimal import optimal_lap_time
        from laplab.vehicle.params import vehicle_preset
    except ImportError:
        return None if line is None else float(line.lap_time)
    return optimal_lap_time(track, vehicle_preset(vehicle_name))


def _evaluations_section(context: ReportContext) -> str:
    parts = ["<section><h2>Evaluations</h2>"]
    evaluations = load_evaluations(context.folder, latest=context.settings.max_evaluations)
    total = len(context.folder.list_evaluations())
    if not evaluations:
        parts.append(_note("No evaluation yet: `laplab evaluate MODEL` runs one."))
        return "".join(parts) + "</section>"
    if total > len(evaluations):
        parts.append(_note(f"The newest {len(evaluations)} of {total} evaluations."))
    lines: dict[str, Any] = {}  # race lines by track name (which carries the direction)
    for evaluation in reversed(evaluations):
        parts.append(_evaluation_html(context, evaluation, lines))
    return "".join(parts) + "</section>"


def _evaluation_html(context: ReportContext, evaluation: Evaluation, lines: dict) -> str:
    stamp = evaluation.stamp
    when = f"{stamp[:4]}-{stamp[4:6]}-{stamp[6:8]} {stamp[8:10]}:{stamp[10:12]}:{stamp[12:]} UTC"
    parts = [f"<article><h3>Evaluation {_esc(stamp)} <span class='sub'>({when})</span></h3>"]
    parts += [f'<p class="error">{_esc(problem)}</p>' for problem in evaluation.problems]
    track, track_problem = context.track, context.track_problem
    if evaluation.track is not None:  # its name says the direction ("name@reversed")
        track, track_problem = _load_track(evaluation.track, bool(evaluation.reverse))
    elif evaluation.reverse is not None:
        track, track_problem = _load_track(context.config.get("track"), evaluation.reverse)
    line = None
    if track is not None:
        key = track.name
        if key not in lines:
            try:
                lines[key] = _raceline(track, car_of_config(context.config))
            except (ValueError, RuntimeError, ArithmeticError) as exc:
                lines[key] = None
                parts.append(_note(f"No race line: {exc}"))
        line = lines[key]
    if track is not None and evaluation.trace is not None and evaluation.trace.size:
        name = f"evaluation-{stamp}.png"
        plot_evaluation(track, evaluation.trace, context.out_dir / name, f"evaluation {stamp} on {track.name}",
                        raceline=None if line is None else line.points,
                        style=context.settings.style)
        parts.append(_figure(name, "Each trial's path; the wide green line is laplab's race line."))
    elif evaluation.trace is None:
        parts.append(_note("This evaluation has no simtrace."))
    elif track is None:
        parts.append(_note(track_problem or "no track"))
    vehicle = car_of_config(context.config)
    optimal = _optimal_lap_time(evaluation, track, vehicle, line) if evaluation.trials else None
    parts.append(_trial_table(evaluation, optimal))
    parts.append(_summary_facts(evaluation))
    parts.append(_video_html(context, evaluation))
    return "".join(parts) + "</article>"


def _trial_table(evaluation: Evaluation, optimal: float | None) -> str:
    """Trials with lap time, completion, off-track count and the gap to the optimal lap (lap time /
    race-line lap time, as ``laplab evaluate`` reports it)."""
    if not evaluation.trials:
        return _note("No trial results (neither summary.json nor the evaluation metrics file).")
    rows = []
    for trial in evaluation.trials:
        gap = trial.lap_time_s / optimal if optimal and trial.lap_time_s is not None else None
        rows.append([trial.trial, trial.status.replace("_", " "), _fmt(trial.completion, 1),
                     _fmt(trial.lap_time_s, 3), _fmt(trial.off_track_count),
                     "–" if gap is None else f"x{gap:.3f}"])
    table = _table(["trial", "status", "completion (%)", "lap time (s)", "off-track", "gap to optimal"], rows)
    if optimal is None:
        return table
    standing = evaluation.standing_start_lap_time
    from_rest = "" if standing is None or standing <= 0 else (f" Each trial starts at rest: the race line driven from rest takes "
                                             f"{standing:.3f} s (x{standing / optimal:.3f}).")
    return table + (f"<p class='sub'>Gap to optimal = lap time / the optimal (race-line) lap, {optimal:.3f} s, a "
                    f"flying lap.{from_rest}</p>")


def _summary_facts(evaluation: Evaluation) -> str:
    """The summary's plain values, top level and inside its ``summary`` object (whatever the
    evaluator reported), folded away under the table."""
    summary = evaluation.summary or {}
    nested = summary.get("summary") if isinstance(summary.get("summary"), dict) else {}
    facts = [(k, v) for k, v in [*summary.items(), *nested.items()]
             if v is None or isinstance(v, (str, int, float, bool))]
    if not facts:
        return ""
    rows = "".join(f"<tr><th>{_esc(k.replace('_', ' '))}</th><td>{_esc(_fmt(v, 3))}</td></tr>" for k, v in facts)
    return f"<details><summary>summary.json</summary><table class='facts'>{rows}</table></details>"


def _video_html(context: ReportContext, evaluation: Evaluation) -> str:
    if evaluation.video is None:
        summary = evaluation.summary or {}
        named = [summary, summary.get("summary") if isinstance(summary.get("summary"), dict) else {}]
        if any(part.get(k) for part in named for k in ("video", "video_path", "video_file")):
            return _note("The video named in summary.json is missing.")
        return ""
    name = f"evaluation-{evaluation.stamp}-video{evaluation.video.suffix.lower()}"
    target = context.out_dir / name
    if not target.exists() or target.stat().st_size != evaluation.video.stat().st_size:
        shutil.copyfile(evaluation.video, target)
    if target.suffix == ".gif":
        return f'<figure><img src="{_esc(name)}" alt="evaluation video"><figcaption>Evaluation video.</figcaption></figure>'
    kind = "video/webm" if target.suffix == ".webm" else "video/mp4"
    return (f'<figure><video controls preload="metadata" src="{_esc(name)}" type="{kind}"></video>'
            f'<figcaption>Evaluation video (<a href="{_esc(name)}">{_esc(name)}</a>).</figcaption></figure>')


# ------------------------------------------------------------------------------------------ page

_CSS = """
body { font-family: system-ui, -apple-system, 'Segoe UI', sans-serif; margin: 0 auto; max-width: 1280px;
       padding: 1.5rem 2rem; color: #1d1d1f; background: #fafafa; }
h1 { margin-bottom: 0.2rem; } h2 { border-bottom: 2px solid #e6a100; padding-bottom: 0.2rem; margin-top: 2.4rem; }
.sub { color: #666; font-size: 0.9rem; font-weight: normal; }
figure { margin: 1rem 0; } figure img, figure video { max-width: 100%; border: 1px solid #ddd; background: #fff; }
figcaption { color: #555; font-size: 0.9rem; margin-top: 0.3rem; }
table { border-collapse: collapse; margin: 0.8rem 0; font-size: 0.92rem; background: #fff; }
th, td { border: 1px solid #ddd; padding: 0.3rem 0.7rem; text-align: left; }
thead th { background: #f0f0f0; } table.facts th { background: #f6f6f6; font-weight: 600; }
.note { color: #666; font-style: italic; } .error { color: #a00000; }
div.error { border: 1px solid #e0b0b0; background: #fff3f3; padding: 0.6rem 1rem; }
article { border-top: 1px solid #ddd; padding-top: 0.6rem; }
"""


def _page(title: str, body: str) -> str:
    return (f"<!DOCTYPE html>\n<html lang='en'><head><meta charset='utf-8'><title>{_esc(title)}</title>"
            f"<meta name='viewport' content='width=device-width, initial-scale=1'><style>{_CSS}</style>"
            f"</head><body>\n{body}\n</body></html>\n")
