"""How long ``laplab import`` takes for a DeepRacer camera model: a front-camera clipped-PPO model
(DEEP_CONVOLUTIONAL_NETWORK_SHALLOW: rl_coach's checkpoint is ~47 MB, as the console's) exported with
``laplab export --format console``, then imported from the folder and from an S3 prefix on moto's
server (127.0.0.1, its own process), as deepracer-for-cloud's ``dr-upload-model`` lays it out.

Prints: the checkpoint's size, the in-process import time from the folder and from S3 (median of
``--repeat``, after one warm-up import that loads torch), and the wall time of one ``laplab import``
command (a fresh Python: imports, torch, the import). Goal (issue 33): under 10 s for a 50 MB
checkpoint on a 2-core machine.

Usage: python bench/import_speed.py [--repeat 3]
"""

from __future__ import annotations

import argparse
import os
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path


def _moto() -> tuple[subprocess.Popen, str]:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    server = subprocess.Popen([sys.executable, "-m", "moto.server", "-H", "127.0.0.1", "-p", str(port)],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    os.environ.update(AWS_ENDPOINT_URL=f"http://127.0.0.1:{port}", AWS_ACCESS_KEY_ID="bench",
                      AWS_SECRET_ACCESS_KEY="bench", AWS_DEFAULT_REGION="us-east-1")
    import boto3
    for _ in range(100):
        try:
            boto3.client("s3").create_bucket(Bucket="bench")
            return server, "s3://bench/drfc/camera-model"
        except Exception:  # noqa: BLE001 - the server is still starting
            time.sleep(0.2)
    server.kill()
    raise SystemExit("moto's server did not start")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    work = Path(tempfile.mkdtemp(prefix="laplab-bench-import-"))
    os.environ["LAPLAB_HOME"] = str(work / "home")

    from laplab.commands.export import _upload_console_folder
    from laplab.env.metadata import ModelMetadata
    from laplab.export.console import export_console
    from laplab.export.deepracer_import import import_deepracer_model
    from laplab.train.config import TrainConfig
    from laplab.train.jobs import create_training

    config = replace(TrainConfig(), model_metadata={**ModelMetadata().to_dict(), "sensor": ["FRONT_FACING_CAMERA"]})
    create_training("camera", config).close()
    folder = export_console("camera", out=work / "camera-console").folder
    size = sum(p.stat().st_size for p in (folder / "model").glob("*.ckpt.*"))
    print(f"rl_coach checkpoint: {size / 1e6:.1f} MB (model/*.ckpt.index, .data, .meta)")

    import_deepracer_model(folder, "warm-up")  # loads torch and the learner classes once
    times = []
    for index in range(args.repeat):
        started = time.perf_counter()
        import_deepracer_model(folder, f"from-folder-{index}")
        times.append(time.perf_counter() - started)
    print(f"import from the folder: {statistics.median(times):.2f} s (median of {args.repeat}, in-process)")

    server, url = _moto()
    try:
        _upload_console_folder(folder, url)
        times = []
        for index in range(args.repeat):
            started = time.perf_counter()
            import_deepracer_model(url, f"from-s3-{index}")
            times.append(time.perf_counter() - started)
        print(f"import from s3 (moto on 127.0.0.1): {statistics.median(times):.2f} s (median of {args.repeat}, "
              "in-process)")
    finally:
        server.kill()
    started = time.perf_counter()
    subprocess.run([sys.executable, "-m", "laplab.cli", "import", str(folder), "--name", "from-cli"], check=True,
                   stdout=subprocess.DEVNULL)
    print(f"`laplab import FOLDER` command, wall time: {time.perf_counter() - started:.2f} s")


if __name__ == "__main__":
    main()
