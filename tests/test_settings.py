"""One settings object (laplab/settings.py): every reader of LAPLAB_HOME agrees, a bad one is one paragraph."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from laplab.errors import UserError
from laplab.settings import Settings, current_settings, use_settings

REPO = Path(__file__).resolve().parents[1]


def every_reader_home() -> dict[str, Path]:
    """laplab's folder as each of the four places that used to resolve LAPLAB_HOME sees it."""
    from laplab.jobs.db import database_path, laplab_home
    from laplab.store.layout import models_root
    from laplab.track.raceline_cache import cache_folder
    from laplab.track.registry import user_track_dir
    return {"jobs.db": laplab_home(), "database": database_path().parent, "store.layout": models_root().parent,
            "track.registry": user_track_dir().parent, "raceline_cache": cache_folder().parent,
            "settings": current_settings().home}


@pytest.mark.parametrize(("value", "expected"), [(None, ".laplab"), ("", ".laplab"), ("rel/home", "rel/home"),
                                                 ("~/lap", "lap"), ("~", ".")])
def test_the_old_resolution_paths_agree(value, expected, tmp_path, monkeypatch):
    monkeypatch.setenv("HOME", str(tmp_path))
    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("LAPLAB_MODELS", raising=False)
    if value is None:
        monkeypatch.delenv("LAPLAB_HOME", raising=False)
    else:
        monkeypatch.setenv("LAPLAB_HOME", value)
    homes = every_reader_home()
    assert set(homes.values()) == {Path(os.path.abspath(tmp_path / expected))}, homes  # an empty one is not the current folder
    assert all(home.is_absolute() for home in homes.values())


def test_a_relative_home_is_fixed_where_it_was_read(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    settings = Settings.from_env({"LAPLAB_HOME": "data"})
    monkeypatch.chdir("/")
    assert settings.home == tmp_path / "data"
    assert settings.to_env() == {"LAPLAB_HOME": str(tmp_path / "data")}  # a child in another folder finds it


def test_the_folders_follow_home_and_the_models_folder_can_move(tmp_path):
    settings = Settings.from_env({"LAPLAB_HOME": str(tmp_path)})
    assert (settings.models_dir, settings.tracks_dir, settings.cache_dir, settings.database, settings.jobs_dir) == (
        tmp_path / "models", tmp_path / "tracks", tmp_path / "cache", tmp_path / "laplab.db", tmp_path / "jobs")
    moved = Settings.from_env({"LAPLAB_HOME": str(tmp_path), "LAPLAB_MODELS": str(tmp_path / "copy")})
    assert moved.models_dir == tmp_path / "copy" and moved.tracks_dir == tmp_path / "tracks"
    assert moved.to_env() == {"LAPLAB_HOME": str(tmp_path), "LAPLAB_MODELS": str(tmp_path / "copy")}
    assert Settings.from_env({"LAPLAB_HOME": str(tmp_path), "LAPLAB_MODELS": ""}) == settings


def one_paragraph_error(environ: dict) -> UserError:
    with pytest.raises(UserError) as caught:
        Settings.from_env(environ)
    text = str(caught.value)
    assert "\n" not in text and "LAPLAB_HOME" in text and caught.value.field == "LAPLAB_HOME", text
    return caught.value


def test_a_home_that_is_a_file_is_one_paragraph(tmp_path):
    (tmp_path / "file").write_text("not a folder")
    error = one_paragraph_error({"LAPLAB_HOME": str(tmp_path / "file")})
    assert "is a file" in str(error) and "folder you can write to" in str(error)
    error = one_paragraph_error({"LAPLAB_HOME": str(tmp_path / "file" / "below")})
    assert f"lies below {tmp_path / 'file'}, which is a file" in str(error)


def test_the_default_home_that_is_a_file_says_the_variable_is_unset(tmp_path, monkeypatch):
    monkeypatch.setenv("HOME", str(tmp_path))
    (tmp_path / ".laplab").write_text("")
    assert "LAPLAB_HOME is not set" in str(one_paragraph_error({}))


def test_a_home_that_cannot_be_written_is_one_paragraph(tmp_path, monkeypatch):
    locked = tmp_path / "locked"
    locked.mkdir(mode=0o500)
    if os.geteuid() == 0:  # root may write anywhere: a folder laplab may not write to, as the system says
        monkeypatch.setattr(os, "access", lambda path, mode: Path(path) != locked)
    try:
        assert "not writable" in str(one_paragraph_error({"LAPLAB_HOME": str(locked)}))
        assert "cannot be made" in str(one_paragraph_error({"LAPLAB_HOME": str(locked / "home")}))
    finally:
        locked.chmod(0o700)


def test_the_command_line_prints_the_paragraph(tmp_path, monkeypatch, capsys):
    from laplab.cli import main
    (tmp_path / "file").write_text("")
    monkeypatch.setenv("LAPLAB_HOME", str(tmp_path / "file"))
    assert main(["tracks", "list"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("laplab tracks: error: LAPLAB_HOME=") and "\n" not in err and "Traceback" not in err


def test_use_settings_leaves_the_environment_alone_and_children_get_its_variables(tmp_path, monkeypatch):
    monkeypatch.setenv("LAPLAB_HOME", str(tmp_path / "env"))
    monkeypatch.delenv("LAPLAB_MODELS", raising=False)
    before = dict(os.environ)
    other = Settings.at(tmp_path / "other").with_models_dir(tmp_path / "copy")
    with use_settings(other):
        from laplab.store.layout import models_root
        assert current_settings() == other and models_root() == tmp_path / "copy"
        assert dict(os.environ) == before
        code = "from laplab.settings import current_settings as c; s = c(); print(s.home, s.models_dir)"
        out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=REPO,
                             env={**current_settings().child_environment(), "PYTHONPATH": str(REPO)}).stdout
        assert out.split() == [str(tmp_path / "other"), str(tmp_path / "copy")]
    assert current_settings() == Settings.at(tmp_path / "env")
    assert "LAPLAB_MODELS" not in Settings.at(tmp_path).child_environment({"LAPLAB_MODELS": "/elsewhere"})


def test_the_python_api_starts_its_jobs_with_the_settings_in_force(tmp_path, monkeypatch):
    import laplab.api as api
    seen = {}
    monkeypatch.setattr(api.subprocess, "run", lambda *a, **k: seen.update(k) or subprocess.CompletedProcess(a, 0, "", ""))
    with use_settings(Settings.at(tmp_path / "notebook")):
        api._run(["leaderboard"], "leaderboard")
    assert seen["env"]["LAPLAB_HOME"] == str(tmp_path / "notebook")


def test_a_console_job_gets_its_folders_from_the_settings(tmp_path, monkeypatch):
    from laplab.jobs.db import Job
    from laplab.jobs.runner import LocalProcessRunner, job_folder, job_mounts, models_dir, owner_cache
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("LAPLAB_HOME", "home")  # relative: a job's process starts in its own folder
    monkeypatch.delenv("LAPLAB_MODELS", raising=False)
    home = tmp_path / "home"
    job = Job(3, "train", "m1", 7, "queued", 0.0, {}, 0.0, None, None, None, None, None, None)
    assert (job_folder(3), models_dir(), owner_cache(7)) == (home / "jobs" / "3", home / "models",
                                                          home / "sandbox" / "user-7" / "cache")
    plain = LocalProcessRunner(sandbox=False).environment(job)
    assert plain["LAPLAB_HOME"] == str(home) and "LAPLAB_MODELS" not in plain
    assert plain["NUMBA_CACHE_DIR"] == str(home / "sandbox" / "user-7" / "cache" / "numba")
    confined = LocalProcessRunner(sandbox=True).environment(job)
    assert confined["LAPLAB_HOME"] == "/tmp/laplab" and confined["NUMBA_CACHE_DIR"] == "/tmp/laplab/cache/numba"
    (home / "tracks").mkdir(parents=True)
    assert job_mounts(job).readonly == {str(home / "tracks"): "/tmp/laplab/tracks"}
