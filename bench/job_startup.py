"""How soon a ``laplab train`` job gets going: seconds from starting the command to its first
environment step, to its first Adam step, and to its exit, and the CPU seconds it used (less
sensitive to a busy host than wall time), for a tiny job (STATE, 2 episodes per
iteration, batch 32, 3 epochs, 4 episodes) in a fresh ``LAPLAB_HOME`` each run.

The command runs as a user runs it (``python -m laplab.cli train ...``: the supervisor forks the
job). A small driver wraps two functions as their modules load, to note the time of their first
call: ``laplab.env.step.EpisodeStepper.step`` (an environment step) and ``torch.optim.adam.adam``
(torch's Adam update, which both ``torch.optim.Adam`` and laplab's FusedAdam call). Nothing else
changes. ``--importtime`` adds one run under ``python -X importtime`` and prints the imports that
took longest (cumulative, the outermost of each chain).

``--code PATH`` times another checkout of laplab (its PYTHONPATH), e.g. an older commit unpacked
with ``git archive COMMIT | tar -x -C /tmp/old`` (run it once first: numba compiles its caches).

Usage: python bench/job_startup.py [--runs 5] [--code PATH] [--importtime]
"""

from __future__ import annotations

import argparse
import json
import os
import re
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from host import host_line  # noqa: E402

TINY = {"num_episodes_between_training": 2, "batch_size": 32, "num_epochs": 3}
MARKS_ENV = "LAPLAB_BENCH_MARKS"

# the driver: notes the first call of each watched function (in the forked job too), then runs laplab
DRIVER = r"""
import importlib.abc, importlib.machinery, os, sys, time
WATCH = {"laplab.env.step": ("EpisodeStepper", "step", "first_env_step"),
         "torch.optim.adam": (None, "adam", "first_adam_step")}

def note(name):
    with open(os.environ["LAPLAB_BENCH_MARKS"], "a") as marks:
        marks.write(f"{name} {time.time()!r}\n")

def watched(function, name):
    def first_call(*args, **kwargs):
        if not first_call.seen:
            first_call.seen = True
            note(name)
        return function(*args, **kwargs)
    first_call.seen = False
    return first_call

class Loader(importlib.abc.Loader):
    def __init__(self, inner, module_name):
        self.inner, self.module_name = inner, module_name
    def create_module(self, spec):
        return self.inner.create_module(spec)
    def exec_module(self, module):
        self.inner.exec_module(module)
        owner_name, attribute, mark = WATCH[self.module_name]
        owner = getattr(module, owner_name) if owner_name else module
        setattr(owner, attribute, watched(getattr(owner, attribute), mark))

class Finder(importlib.abc.MetaPathFinder):
    def find_spec(self, fullname, path, target=None):
        if fullname not in WATCH:
            return None
        spec = importlib.machinery.PathFinder.find_spec(fullname, path)
        if spec is not None:
            spec.loader = Loader(spec.loader, fullname)
        return spec

sys.meta_path.insert(0, Finder())
from laplab.cli import main
sys.exit(main())
"""


def run_job(code: Path, importtime: bool = False) -> tuple[dict[str, float], str]:
    """One tiny job in a fresh LAPLAB_HOME: seconds from launch to each mark and to exit, and the
    ``-X importtime`` report (empty unless ``importtime``)."""
    with tempfile.TemporaryDirectory(prefix="laplab-start-") as home:
        marks = Path(home) / "marks.txt"
        env = {**os.environ, "PYTHONPATH": str(code), "LAPLAB_HOME": home, MARKS_ENV: str(marks)}
        env.pop("LAPLAB_SUPERVISOR", None)
        command = [sys.executable, *(["-X", "importtime"] if importtime else []), "-c", DRIVER, "train",
                   "--name", "start", "--hyperparameters", json.dumps(TINY), "--max-episodes", "4", "--quiet"]
        cpu_before = _children_cpu()
        start = time.time()
        done = subprocess.run(command, env=env, cwd=home, capture_output=True, text=True, timeout=600)
        exited = time.time() - start
        if done.returncode != 0:
            raise SystemExit(f"the job failed ({done.returncode}):\n{done.stderr[-3000:]}")
        times = {"exit": exited, "cpu": _children_cpu() - cpu_before}
        for line in marks.read_text().splitlines():
            name, stamp = line.split()
            times.setdefault(name, float(stamp) - start)
        return times, done.stderr if importtime else ""


def _children_cpu() -> float:
    """CPU seconds (user + system) of this process's finished children and theirs."""
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def slowest_imports(report: str, count: int = 15) -> list[tuple[float, str]]:
    """The ``count`` costliest imports of an importtime report outside laplab: cumulative seconds of
    each, leaving out those inside one already listed."""
    rows = []
    for line in report.splitlines():
        match = re.match(r"import time:\s+\d+ \|\s+(\d+) \|( *)(\S+)", line)
        if match:
            rows.append((int(match.group(1)) / 1e6, len(match.group(2)) // 2, match.group(3)))
    picked: dict[int, tuple[float, str]] = {}
    for index in sorted(range(len(rows)), key=lambda i: -rows[i][0]):
        seconds, depth, name = rows[index]
        if name.startswith("laplab") or len(picked) == count:
            continue
        enclosing = []  # a module is printed after its children, one level shallower
        for later in range(index + 1, len(rows)):
            if rows[later][1] < depth:
                depth = rows[later][1]
                enclosing.append(later)
        if not any(i in picked for i in enclosing):
            picked[index] = (seconds, name)
    return sorted(picked.values(), reverse=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--code", type=Path, default=Path(__file__).resolve().parents[1],
                        help="the laplab checkout to time (default: this one)")
    parser.add_argument("--importtime", action="store_true", help="one more run under -X importtime")
    args = parser.parse_args()
    print(host_line(), f"| load average {os.getloadavg()[0]:.2f} | code {args.code}")
    run_job(args.code)  # warm-up: the page cache, numba's caches
    runs = [run_job(args.code)[0] for _ in range(args.runs)]
    for name in ("first_env_step", "first_adam_step", "exit", "cpu"):
        values = [run[name] for run in runs]
        print(f"{name:16s} median {statistics.median(values):5.2f} s  (runs: "
              + " ".join(f"{v:.2f}" for v in values) + ")")
    print(f"load average after: {os.getloadavg()[0]:.2f}")
    if args.importtime:
        _, report = run_job(args.code, importtime=True)
        print("slowest imports (cumulative s, under -X importtime):")
        for seconds, name in slowest_imports(report):
            print(f"  {seconds:6.3f}  {name}")


if __name__ == "__main__":
    main()
