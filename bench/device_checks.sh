#!/usr/bin/env bash
# The checks that need a GPU machine (16 cores, one GPU), as one prepared run of at most ~9 minutes:
# the learner on CUDA (tests/train/test_learner_device.py), a camera model's time to lap with the learner
# on the GPU against the CPU, and with 14 Ray rollout workers, the collection's scaling 1 -> 14 Ray workers, and the
# camera's frames/s on 16 cores. Each stage has its own time limit and appends to $OUT/device.log, so
# a stage that runs over still leaves the others' figures.
#
#   bash bench/device_checks.sh            # on the device machine (docs/scaleout.md, "GPU")
#   QUICK=1 bash bench/device_checks.sh    # a short rehearsal on any machine (2 workers, no CUDA needed)
#   STAGES="machine learner-on-cuda" bash bench/device_checks.sh   # only the named stages
#
# Where laplab's dependencies are missing (the device image has torch and numba, not Ray or
# gymnasium), `bash bench/device_wheels.sh` puts them in .whl/ as cp312 wheels; carry .whl (and .gpu, holding
# reinvent_base.npy for the camera stage) and they are installed first.
set -u
OUT=${OUT:-/tmp/device-out}
mkdir -p "$OUT"
LOG=$OUT/device.log
export PYTHONUNBUFFERED=1
if [ -d .whl ] && ls .whl/*.whl >/dev/null 2>&1; then
    python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl \
        && export PYTHONPATH=/tmp/site:$PWD${PYTHONPATH:+:$PYTHONPATH}
fi
export PYTHONPATH=$PWD${PYTHONPATH:+:$PYTHONPATH}
export LAPLAB_HOME=${LAPLAB_HOME:-/tmp/laplab-home}
if [ -d .gpu ]; then  # a route for sensor_speed.py, where ../shared is not on the machine
    mkdir -p ../shared/reference-tracks && cp -n .gpu/*.npy ../shared/reference-tracks/ 2>/dev/null
fi

stage() {  # stage NAME SECONDS COMMAND...: run with a time limit, log its output and wall time
    local name=$1 limit=$2; shift 2
    if [ -n "${STAGES:-}" ] && [[ " $STAGES " != *" $name "* ]]; then return; fi  # STAGES="a b": only those
    local start=$SECONDS
    echo "=== $name ($(date -u +%H:%M:%S), limit ${limit}s): $*" | tee -a "$LOG"
    timeout --kill-after=10 "$limit" "$@" 2>&1 | tee -a "$LOG" | tail -n 60
    echo "=== $name: rc ${PIPESTATUS[0]} in $((SECONDS - start)) s" | tee -a "$LOG"
}

if [ -n "${QUICK:-}" ]; then
    WORKERS="1 2"; MANY=2; EPISODES=4; BUDGET=40; DEVICE=cpu
else
    WORKERS="1 4 14"; MANY=14; EPISODES=28; BUDGET=200; DEVICE=cuda
fi

stage machine 30 bash -c 'nproc; free -g | head -2; nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv 2>/dev/null;
    python3 -c "import sys, numpy, numba, torch; print(sys.version.split()[0], \"numpy\", numpy.__version__, \"numba\", numba.__version__,
    \"torch\", torch.__version__, \"cuda\", torch.cuda.is_available()); import ray, gymnasium, laplab; print(\"ray\", ray.__version__)";
    lscpu | grep -E "Model name|Flags" | sed "s/Flags:.*avx512_bf16.*/AVX512-BF16: yes/; s/Flags:.*/AVX512-BF16: no/"'
stage learner-on-cuda 110 python3 -m pytest -q -x -p no:cacheprovider tests/train/test_learner_device.py
stage time-to-lap-gpu 90 python3 bench/time_to_lap.py --tracks classic_2018 --seeds 0 --console ppo-discrete \
    --device "$DEVICE" --budget 60
stage time-to-lap-cpu 90 python3 bench/time_to_lap.py --tracks classic_2018 --seeds 0 --console ppo-discrete \
    --budget 60
stage time-to-lap-workers 300 python3 bench/time_to_lap.py --tracks classic_2018 --seeds 0 --console ppo-discrete \
    --workers "$MANY" --device "$DEVICE" --budget "$BUDGET"
# shellcheck disable=SC2086
stage scaleout 130 python3 bench/scaleout.py --sensors FRONT_FACING_CAMERA --workers $WORKERS \
    --episodes "$EPISODES" --iterations 2 --trained-seconds 20
# The simulator as on the 2-core host: two of this machine's cores, two numba threads (issue 29's 1 M
# car-steps/s is a 2-core figure; this separates the code from the host it was measured on).
stage env-speed-2core 150 env NUMBA_NUM_THREADS=2 OMP_NUM_THREADS=2 taskset -c 0,1 python3 bench/env_speed.py \
    --repeats 3 --steps 200
stage camera-frames 40 python3 bench/sensor_speed.py --look-only --runs 3
echo "=== done ($(date -u +%H:%M:%S))" | tee -a "$LOG"
