"""The object-store modules keep store/ the bottom layer, and laplab imports boto3 only when asked."""

from __future__ import annotations

import subprocess
import sys

from tests.test_package_layers import PACKAGE, imports_of


def test_store_imports_nothing_of_laplab_above_it():
    # the package root (its version) is not above; laplab.errors and laplab.settings are the standard
    # library only (any layer)
    below = ("laplab", "laplab.errors", "laplab.settings")
    above = {f: sorted(m for m in mods if m not in below and not m.startswith("laplab.store"))
             for f, mods in imports_of("store").items()}
    assert not {f: m for f, m in above.items() if m}


def test_the_command_line_does_not_import_boto3_without_a_store():
    code = ("import sys, laplab.cli; laplab.cli.build_parser(); import laplab.store.s3, laplab.store.remote; "
            "print('boto3' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=PACKAGE.parent,
                         env={"PYTHONPATH": str(PACKAGE.parent), "PATH": "/usr/bin:/bin"})
    assert out.stdout.strip() == "False", out.stderr[-2000:]


def test_a_checkpoints_resume_state_travels_with_it():
    from laplab.store.remote import checkpoint_of
    assert checkpoint_of("model/3_Step-112.ckpt") == "3_Step-112.ckpt"
    assert checkpoint_of("model/3_Step-112.ckpt.resume") == "3_Step-112.ckpt"
    assert checkpoint_of("model/model_metadata.json") is None
    assert checkpoint_of("0/training-simtrace/3-iteration.csv") is None
