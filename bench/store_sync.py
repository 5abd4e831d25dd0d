"""What publishing a training job to an S3-compatible store costs: the same tiny job trained into a
local folder and into moto's server on 127.0.0.1 (its own process), in one run, after a warm-up job;
the store sync's own time per iteration.

Prints: wall time of each job, the sync's seconds per iteration (upload of simtrace, metrics, robomaker
log, checkpoint and index; in a background thread, so the job waits only for the last one), files
uploaded, and the bucket's size for the model. Figures depend on the store (moto is a Python server
that keeps objects in memory; a remote S3 adds network time per file).

Usage: python bench/store_sync.py [--episodes 40] [--sensor STATE|FRONT_FACING_CAMERA]
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import subprocess
import sys
import tempfile
import time
from dataclasses import replace


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=40)
    parser.add_argument("--sensor", default="STATE")
    args = parser.parse_args()

    with socket.socket() as probe:  # moto's server in a process of its own, as a store would be
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    server = subprocess.Popen([sys.executable, "-m", "moto.server", "-H", "127.0.0.1", "-p", str(port)],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    home = tempfile.mkdtemp(prefix="laplab-bench-store-")
    os.environ.update(AWS_ENDPOINT_URL=f"http://127.0.0.1:{port}", AWS_ACCESS_KEY_ID="bench",
                      AWS_SECRET_ACCESS_KEY="bench", AWS_DEFAULT_REGION="us-east-1", LAPLAB_HOME=home)
    import boto3
    for _ in range(100):
        try:
            boto3.client("s3").create_bucket(Bucket="bench")
            break
        except Exception:  # noqa: BLE001 - the server is still starting
            time.sleep(0.2)

    from laplab.commands.store_option import StoreSession
    from laplab.env.metadata import metadata_from_dict
    from laplab.store.layout import MODELS_ROOT_ENV
    from laplab.train.config import TrainConfig
    from laplab.train.jobs import create_training

    base = TrainConfig(track="oval", max_episodes=args.episodes)
    config = replace(base, model_metadata=metadata_from_dict({**base.model_metadata.to_dict(), "sensor": [args.sensor]}))
    config = replace(config, hyperparameters=replace(config.hyper(), num_episodes_between_training=4,
                                                     batch_size=32, num_epochs=3))

    warmup = create_training("warmup", replace(config, max_episodes=4))  # compiles numba kernels, warms torch
    warmup.run()
    warmup.close()
    started = time.perf_counter()
    local = create_training("local-run", config)
    local_result = local.run()
    local.close()
    local_s = time.perf_counter() - started

    session = StoreSession("s3://bench/models", "bench")
    os.environ[MODELS_ROOT_ENV] = str(session.root)
    started = time.perf_counter()
    listeners = session.create_job("store-run")
    remote = create_training("store-run", config, listeners=listeners)
    remote_result = remote.run()
    session.finish()
    remote.close()
    session.close()
    store_s = time.perf_counter() - started
    sync = listeners[0]
    size = sum(info[0] for info in session.remote.listing("store-run").values())
    print(f"sensor {args.sensor}, {args.episodes} episodes, 4 per iteration (2 cores shared: loaded figures)")
    print(f"local folder : {local_s:6.2f} s for {local_result.iterations} iterations")
    print(f"S3 store     : {store_s:6.2f} s for {remote_result.iterations} iterations; "
          f"sync {sync.seconds:.2f} s in all = {1000 * sync.seconds / max(remote_result.iterations, 1):.0f} ms "
          f"per iteration, {sync.uploads} files uploaded, {size / 1e6:.2f} MB in the bucket")
    print(json.dumps({"local_s": local_s, "store_s": store_s, "sync_s": sync.seconds, "uploads": sync.uploads,
                      "iterations": remote_result.iterations, "bucket_bytes": size}))
    server.terminate()
    server.wait()


if __name__ == "__main__":
    main()
