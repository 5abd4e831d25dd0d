"""docs/gymnasium.md cannot rot: every Python block marked ``<!-- test -->`` runs as written, each in a
fresh namespace, with the training budgets (``TOTAL_TIMESTEPS``, ``NUM_ENVS``) cut down."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

DOC = Path(__file__).resolve().parents[2] / "docs" / "gymnasium.md"
MARKER = "<!-- test -->"
# Budget lines of the doc's training examples and what the test runs instead.
OVERRIDES = {"TOTAL_TIMESTEPS": "512", "NUM_ENVS": "2"}
_BLOCK = re.compile(r"^<!-- test -->\n```python\n(.*?)^```\s*$", re.MULTILINE | re.DOTALL)


def marked_blocks() -> list[tuple[int, str]]:
    """(line number, code) of each marked block, in document order."""
    text = DOC.read_text(encoding="utf-8")
    return [(text.count("\n", 0, match.start(1)) + 1, match.group(1)) for match in _BLOCK.finditer(text)]


def with_small_budget(code: str) -> tuple[str, set[str]]:
    """``code`` with each ``NAME = value`` budget line of OVERRIDES replaced; returns the names replaced."""
    replaced = set()
    for name, value in OVERRIDES.items():
        code, count = re.subn(rf"^{name} = .*$", f"{name} = {value}", code, flags=re.MULTILINE)
        if count:
            replaced.add(name)
    return code, replaced


def test_the_doc_marks_its_examples():
    blocks = marked_blocks()
    assert DOC.read_text(encoding="utf-8").count(MARKER) == len(blocks), \
        f"a {MARKER} marker in {DOC.name} is not directly followed by a ```python block"
    assert len(blocks) >= 7
    training = [code for _, code in blocks if ".learn(" in code]
    assert len(training) == 2, "the two Stable-Baselines3 examples are no longer marked for testing"
    for code in training:
        assert with_small_budget(code)[1] == {"TOTAL_TIMESTEPS", "NUM_ENVS"}, \
            "a training example no longer sets TOTAL_TIMESTEPS and NUM_ENVS, which this test shrinks"


@pytest.mark.parametrize("line,code", marked_blocks(), ids=lambda value: f"line{value}" if isinstance(value, int) else "")
def test_doc_block_runs(line, code, tmp_path, monkeypatch, capsys):
    if "stable_baselines3" in code:
        pytest.importorskip("stable_baselines3")
    monkeypatch.chdir(tmp_path)  # the examples may save files (model.save)
    small, _ = with_small_budget(code)
    exec(compile(small, f"{DOC.name}, block at line {line}", "exec"), {"__name__": "__doc_example__"})
    assert capsys.readouterr().out.strip(), "a documented example printed nothing"
