#!/usr/bin/env bash
# Fill .whl/ with the cp312 wheels bench/device_checks.sh needs on a GPU machine whose Python (3.12)
# has torch, numba, numpy and friends but not Ray, gymnasium, shapely or zstandard, and no network.
# Ray's wheel (79 MB) is repacked without what laplab never imports (the Java jars, the dashboard's web
# build, RLlib, Ray Data, Serve, Tune, Train) to about 39 MB, so everything travels within a 64 MiB
# working-tree limit.
#
#   bash bench/device_wheels.sh      # then carry .whl (ignored by git: add /.whl/ to .git/info/exclude)
set -eu
cd "$(dirname "$0")/.."
mkdir -p .whl
platforms="--platform manylinux_2_28_x86_64 --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 --platform any"
# shellcheck disable=SC2086
python3 -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp $platforms -d .whl \
    ray==2.60.0 gymnasium farama-notifications shapely zstandard jsonschema jsonschema-specifications referencing rpds-py
python3 - <<'EOF'
import pathlib, shutil, tempfile, zipfile

wheel = next(pathlib.Path(".whl").glob("ray-2.60.0-cp312-*.whl"))
unused = ("ray/jars/", "ray/dashboard/client/build/", "ray/rllib/", "ray/data/", "ray/serve/", "ray/tune/",
          "ray/train/", "ray/llm/")
with tempfile.NamedTemporaryFile(dir=".whl", suffix=".tmp", delete=False) as handle:
    repacked = pathlib.Path(handle.name)
with zipfile.ZipFile(wheel) as source, zipfile.ZipFile(repacked, "w", zipfile.ZIP_DEFLATED, compresslevel=9) as target:
    for item in source.infolist():
        if not item.filename.startswith(unused):
            target.writestr(item, source.read(item))
shutil.move(repacked, wheel)
print(f"{wheel.name}: {wheel.stat().st_size / 1e6:.1f} MB")
EOF
du -sh .whl
