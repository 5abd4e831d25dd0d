"""TensorFlow and OpenVINO stay inside laplab/export, imported only when an export runs: importing the
CLI, the export modules or the robomaker log writer loads neither them nor torch."""

import subprocess
import sys

CODE = """
import sys
import laplab.cli, laplab.commands.export, laplab.store.robomaker_log
import laplab.export.car, laplab.export.console, laplab.export.tensorflow_graph, laplab.export.openvino_model
import laplab.export.policy_layers, laplab.export.tensorflow_checkpoint
print(sorted(m for m in ('torch', 'tensorflow', 'openvino') if m in sys.modules))
"""


def test_export_modules_import_no_heavy_framework():
    out = subprocess.run([sys.executable, "-c", CODE], capture_output=True, text=True, check=True)
    assert out.stdout.strip().splitlines()[-1] == "[]", out.stdout + out.stderr
