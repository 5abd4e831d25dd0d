"""``--store`` works on a local copy without touching ``os.environ``: its settings travel with the call."""

from __future__ import annotations

import argparse
import os
from pathlib import Path

from laplab.commands.store_option import store_session
from laplab.settings import current_settings
from laplab.store.layout import models_root


def test_a_store_session_moves_the_models_folder_and_leaves_the_environment_alone(store_url, s3_env, monkeypatch):
    home = Path(os.environ["LAPLAB_HOME"])
    writes = []
    monkeypatch.setattr(os, "putenv", lambda key, value: writes.append(key))
    monkeypatch.setattr(os, "unsetenv", lambda key: writes.append(key))
    before = dict(os.environ)
    with store_session(argparse.Namespace(store=store_url), "evaluate") as session:
        assert session.root.parent == home / "cache" / "store" and session.root.is_dir()
        assert models_root() == session.root == current_settings().models_dir
        assert current_settings().home == home  # only the models move
        assert current_settings().child_environment()["LAPLAB_MODELS"] == str(session.root)
        assert dict(os.environ) == before
    assert models_root() == home / "models" and not session.root.exists()
    assert dict(os.environ) == before and not writes


def test_a_store_command_writes_no_variable(store_url, s3_env, monkeypatch, capsys):
    from laplab.cli import main
    writes = []
    monkeypatch.setattr(os, "putenv", lambda key, value: writes.append(key))
    monkeypatch.setattr(os, "unsetenv", lambda key: writes.append(key))
    assert main(["leaderboard", "--json", "--store", store_url]) == 0
    assert capsys.readouterr().out.strip() == "[]"
    assert not [key for key in writes if "LAPLAB" in str(key)]
