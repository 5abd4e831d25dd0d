"""Example DeepRacer reward functions, each a complete ``reward_function.py`` file.

Load one with ``load_reward_function(example_path("follow_centerline"))``; copy a file to start
your own. Every example runs unchanged on AWS DeepRacer (they use only ``math``).
"""

from __future__ import annotations

from pathlib import Path

EXAMPLES_DIR = Path(__file__).resolve().parent


def example_names() -> list[str]:
    """Names of the shipped examples (file names without ``.py``), sorted."""
    return sorted(path.stem for path in EXAMPLES_DIR.glob("*.py") if not path.stem.startswith("_"))


def example_path(name: str) -> Path:
    """Path of the example ``name`` (with or without ``.py``)."""
    path = EXAMPLES_DIR / f"{name.removesuffix('.py')}.py"
    if name.startswith("_") or not path.is_file():
        raise ValueError(f"no reward example named {name!r}; known: {', '.join(example_names())}")
    return path
