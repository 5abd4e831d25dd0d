"""Imports flow one way (docs/architecture.md): checked on the source, without importing it."""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "laplab"


def laplab_imports(path: Path) -> set[str]:
    names = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("laplab"):
            names.add(node.module)
        elif isinstance(node, ast.Import):
            names |= {alias.name for alias in node.names if alias.name.startswith("laplab")}
    return names


def imports_of(package: str) -> dict[str, set[str]]:
    return {str(p.relative_to(PACKAGE)): laplab_imports(p) for p in (PACKAGE / package).rglob("*.py")}


def test_reward_does_not_import_env():
    bad = {f: [m for m in mods if m.startswith("laplab.env")] for f, mods in imports_of("reward").items()}
    assert not {f: m for f, m in bad.items() if m}


def test_the_settings_import_nothing_of_laplab_but_its_errors():
    # laplab/settings.py sits below store/ (the bottom layer), so every layer may ask it where files live
    assert laplab_imports(PACKAGE / "settings.py") <= {"laplab.errors"}
    assert laplab_imports(PACKAGE / "errors.py") == set()


def test_only_the_settings_read_or_write_laplab_home():
    import re
    access = re.compile(r"""(environ\s*(\.\w+\s*\(|\[)|getenv\s*\(|putenv\s*\()\s*["'](LAPLAB_HOME|LAPLAB_MODELS)["']""")
    readers = {str(p.relative_to(PACKAGE)) for p in PACKAGE.rglob("*.py") if access.search(p.read_text())}
    assert not readers, readers  # laplab.settings.current_settings() is the one way (to_env() for children)
    assert access.search('os.environ["LAPLAB_HOME"] = x') and access.search("os.environ.get('LAPLAB_MODELS')")


def test_commands_take_user_error_from_below_the_cli():
    bad = {f: mods for f, mods in imports_of("commands").items() if "laplab.cli" in mods}
    assert not bad
    from laplab.cli import UserError as from_cli
    from laplab.errors import UserError
    assert from_cli is UserError


def test_the_model_spec_and_learner_interface_import_without_torch():
    import subprocess
    import sys
    code = ("import sys, laplab.env.spec, laplab.agents.learner, laplab.train.events; "
            "print('torch' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         cwd=PACKAGE.parent, env={"PYTHONPATH": str(PACKAGE.parent), "PATH": "/usr/bin:/bin"})
    assert out.stdout.strip() == "False", out.stderr[-2000:]
