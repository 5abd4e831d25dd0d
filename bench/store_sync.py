"""What publishing a training job to an S3-compatible store costs: the same tiny job trained into a
local folder and into moto's server on 127.0.0.1, in one run; the store sync's own time per iteration.

Prints: wall time of each job, the sync's seconds per iteration (upload of simtrace, metrics, robomaker
log, checkpoint and index), files uploaded, and the bucket's size for the model. Figures depend on the
store (moto keeps objects in memory in this process; a remote S3 adds network time per file).

Usage: python bench/store_sync.py [--episodes 40] [--sensor STATE|FRONT_FACING_CAMERA]
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from dataclasses import replace
from pathlib import Path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=40)
    parser.add_argument("--sensor", default="STATE")
    args = parser.parse_args()

    from moto.server import ThreadedMotoServer
    server = ThreadedMotoServer(ip_address="127.0.0.1", port=0, verbose=False)
    server.start()
    host, port = server.get_host_and_port()
    home = tempfile.mkdtemp(prefix="laplab-bench-store-")
    os.environ.update(AWS_ENDPOINT_URL=f"http://{host}:{port}", AWS_ACCESS_KEY_ID="bench",
                      AWS_SECRET_ACCESS_KEY="bench", AWS_DEFAULT_REGION="us-east-1", LAPLAB_HOME=home)
    import boto3
    boto3.client("s3").create_bucket(Bucket="bench")

    from laplab.commands.store_option import StoreSession
    from laplab.env.metadata import metadata_from_dict
    from laplab.store.layout import MODELS_ROOT_ENV
    from laplab.train.config import TrainConfig
    from laplab.train.jobs import create_training

    base = TrainConfig(track="oval", max_episodes=args.episodes)
    config = replace(base, model_metadata=metadata_from_dict({**base.model_metadata.to_dict(), "sensor": [args.sensor]}))
    config = replace(config, hyperparameters=replace(config.hyper(), num_episodes_between_training=4,
                                                     batch_size=32, num_epochs=3))

    started = time.perf_counter()
    local = create_training("local-run", config)
    local_result = local.run()
    local.lock.release()
    local_s = time.perf_counter() - started

    session = StoreSession("s3://bench/models", "bench")
    os.environ[MODELS_ROOT_ENV] = str(session.root)
    started = time.perf_counter()
    listeners = session.create_job("store-run")
    remote = create_training("store-run", config, listeners=listeners)
    remote_result = remote.run()
    session.finish()
    remote.lock.release()
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
    server.stop()


if __name__ == "__main__":
    main()
