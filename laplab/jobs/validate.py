"""Reward-function validation for the console, in a confined process (the source is untrusted).

``python -m laplab.jobs.validate`` reads ``{source, track, model_metadata}`` as JSON on stdin and
prints ``{ok, errors: [{line, message}], calls, minimum, mean, maximum}``: the same sweep and the
same messages as ``laplab reward validate``.
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
from pathlib import Path

VALIDATION_TIMEOUT_S = 60.0


def _validate(request: dict) -> dict:
    from laplab.env.metadata import metadata_from_dict
    from laplab.env.vector import resolve_metadata
    from laplab.reward.errors import RewardFunctionError
    from laplab.reward.loader import load_reward_function
    from laplab.reward.validate import validate_reward_function
    from laplab.sim.race_type import RaceType
    from laplab.track.registry import DEFAULT_TRACK, load_track

    track = load_track(request.get("track") or DEFAULT_TRACK)
    meta = request.get("model_metadata")
    metadata = metadata_from_dict(meta, "model_metadata") if meta else resolve_metadata(None)
    source = request["source"]
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "reward_function.py"
        path.write_text(source, encoding="utf-8")
        try:
            reward_fn = load_reward_function(str(path), max_speed=metadata.action_space.max_speed)
            race = RaceType.from_dict(request.get("race_type"), "race_type")
            race.check_track(track.length, track.name)
            report = validate_reward_function(reward_fn, track, metadata.action_space.sweep_actions(), isolate=True,
                                              race=race if race.has_objects else None)
        except RewardFunctionError as exc:
            return {"ok": False, "errors": [_error(exc, path)], "calls": 0}
    if report.passed:
        return {"ok": True, "errors": [], "calls": report.calls, "minimum": report.minimum, "mean": report.mean,
                "maximum": report.maximum, "track": track.name}
    return {"ok": False, "errors": [_error(report.error, path)], "calls": report.calls, "track": track.name}


def _error(exc, path: Path) -> dict:
    return {"line": exc.lineno, "message": str(exc).replace(str(path), "reward_function.py")}


def main() -> int:
    from laplab.cli import user_error_types
    try:
        request = json.loads(sys.stdin.read())
        answer = _validate(request)
    except MemoryError:
        answer = {"ok": False, "errors": [{"line": None, "message": "the reward function ran out of memory"}]}
    except user_error_types() as exc:
        answer = {"ok": False, "errors": [{"line": None, "message": str(exc)}], "input_error": True}
    print(json.dumps(answer))
    return 0


def validate_confined(source: str, track: str | None, model_metadata: dict | None, owner: int,
                      sandbox: bool | None = None, race_type: dict | None = None) -> dict:
    """Run the validation in a confined child process; returns its answer (a dict as above).
    ``race_type`` (a RaceType's dict) puts the race's objects on the track."""
    from laplab.jobs.confinement import SANDBOX_HOME, JobLimits, Mounts, bubblewrap_works, clean_environment, confined_command, limits_preexec
    from laplab.settings import Settings, current_settings
    settings = current_settings()
    use = bubblewrap_works() if sandbox is None else sandbox
    readonly = {}
    tracks = settings.tracks_dir
    if tracks.is_dir():
        readonly[str(tracks)] = f"{SANDBOX_HOME}/tracks"
    scratch = Path(tempfile.mkdtemp(prefix="laplab-validate-"))
    from laplab.jobs.runner import owner_cache
    cache = owner_cache(owner)  # never shared between users (numba's cache is code)
    cache.mkdir(parents=True, exist_ok=True)
    from laplab.jobs.warmup import seed
    seed(cache / "numba", settings.home)
    try:
        mounts = Mounts({str(scratch): f"{SANDBOX_HOME}/job", str(cache): f"{SANDBOX_HOME}/cache"}, readonly)
        where = (Settings.at(SANDBOX_HOME) if use else settings).to_env()
        env = clean_environment({**where, "NUMBA_CACHE_DIR": f"{SANDBOX_HOME}/cache/numba" if use else str(cache / "numba")},
                                sandboxed=use)
        command = confined_command([sys.executable, "-m", "laplab.jobs.validate"], mounts, use)
        request = json.dumps({"source": source, "track": track, "model_metadata": model_metadata,
                              "race_type": race_type})
        try:
            done = subprocess.run(command, input=request.encode(), capture_output=True, env=env,
                                  timeout=VALIDATION_TIMEOUT_S, preexec_fn=limits_preexec(JobLimits.console(cpu_seconds=120)),
                                  cwd=None if use else str(scratch))
        except subprocess.TimeoutExpired:
            return {"ok": False, "errors": [{"line": None, "message": f"validation did not finish within "
                                             f"{VALIDATION_TIMEOUT_S:g} s"}]}
        lines = done.stdout.decode(errors="replace").strip().splitlines()
        try:
            return json.loads(lines[-1])
        except (IndexError, ValueError):
            # not its output: whatever the reward function printed (files, the environment) stays out of the answer
            return {"ok": False, "errors": [{"line": None, "message": (
                f"the validation ended without an answer (exit status {done.returncode}): the reward function "
                "ended its process (os._exit, a signal, a crash) or used up its limits")}]}
    finally:
        import shutil
        shutil.rmtree(scratch, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
