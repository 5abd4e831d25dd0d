"""Console jobs on a Ray cluster: ``laplab serve --ray-address ADDR [--rollout-workers N]``.

A console started with a cluster address runs the rollout workers of its training jobs (train,
clone, resume) on that cluster, with the CLI's code (:class:`laplab.cluster.launch.RayWorkers`);
the learner stays in the job's confined process on the console's machine. Its evaluate jobs (race
submissions' included) drive their laps on one of the cluster's nodes
(:mod:`laplab.cluster.evaluations`) and write the result into the model's folder from the job. Such a job keeps the
machine's network (bubblewrap's ``--share-net``) and nothing else: no database, no secret key, no
other user's folder. Since its process sees neither the machine's ``/tmp`` nor ``/dev/shm`` (where a
Ray node keeps its sockets and object store), a sandboxed job joins through Ray Client,
``ray://HEAD:10001`` (``ray start --head`` starts that server). Exports stay in-process and
offline. See docs/console.md ("Jobs on a Ray cluster") for the threat model.
"""

from __future__ import annotations

import importlib.util
import ipaddress
import socket
from dataclasses import dataclass, field
from typing import Callable

from laplab.train.errors import JobError

DEFAULT_ROLLOUT_WORKERS = 2
TRAINING_KINDS = ("train", "clone", "resume")  # the jobs whose rollout workers run on the cluster
CLUSTER_KINDS = (*TRAINING_KINDS, "evaluate")  # ... and the jobs whose laps run there (laplab.cluster.evaluations)


@dataclass(frozen=True)
class RayCluster:
    """The cluster a console's training jobs use: its ``address`` and ``workers``, the rollout
    workers of a job (a request may ask for fewer: ``workers`` in the API); ``auth``: the variables
    of Ray's token authentication the jobs get (:meth:`at`), never written to a file."""

    address: str
    workers: int = DEFAULT_ROLLOUT_WORKERS
    auth: dict = field(default_factory=dict, repr=False)

    @classmethod
    def at(cls, address: str, workers: int = DEFAULT_ROLLOUT_WORKERS) -> "RayCluster":
        """The cluster at ``address`` with the token this server's user has (RAY_AUTH_TOKEN,
        RAY_AUTH_TOKEN_PATH or ~/.ray/auth_token), if any."""
        from laplab.cluster.collector import ray_auth_environment
        return cls(address, workers, ray_auth_environment())

    def to_spec(self) -> dict:
        """What the job's spec.json says (the token goes in its environment only)."""
        return {"address": self.address, "workers": self.workers}

    def job_environment(self) -> dict[str, str]:
        return dict(self.auth)


def _host_of(address: str) -> str:
    return address.split("://", 1)[-1].rpartition(":")[0].strip("[]")


def runs_on_this_machine(address: str) -> bool:
    """Whether the head at ``address`` is this machine (a loopback or one of its own addresses)."""
    host = _host_of(address)
    try:
        if ipaddress.ip_address(host).is_loopback:
            return True
    except ValueError:
        if host == "localhost":
            return True
    try:
        mine = set(socket.gethostbyname_ex(socket.gethostname())[2])
        return bool(mine & set(socket.gethostbyname_ex(host)[2]))
    except OSError:
        return False


def check_console_cluster(address: str, workers: int, sandboxed: bool) -> list[str]:
    """Check a console's cluster before the server starts: a :class:`JobError` paragraph for what
    cannot work, the warnings (sentences) for what works but weakens the isolation."""
    if isinstance(workers, bool) or not isinstance(workers, int) or not 1 <= workers <= 1024:
        raise JobError(f"--rollout-workers must be an integer within 1..1024, got {workers!r}")
    if importlib.util.find_spec("ray") is None:
        raise JobError("--ray-address runs the training jobs' rollout workers on Ray, which is not installed here: "
                       "pip install -e \".[console,cluster]\" (ray[default]==2.60.0, the cluster's version), "
                       "or serve without --ray-address")
    if sandboxed and not address.startswith("ray://"):
        host = _host_of(address) or "HEAD"
        raise JobError(f"--ray-address {address}: console jobs run sandboxed (bubblewrap), without this machine's "
                       "/tmp and /dev/shm where a Ray node keeps its sockets and object store, so they join the "
                       f"cluster through Ray Client: --ray-address ray://{host}:10001 (the client server that "
                       "`ray start --head` starts, port 10001 unless --ray-client-server-port says otherwise)")
    from laplab.cluster.collector import check_reachable
    check_reachable(address, otherwise="serve without --ray-address: each job then collects in its own process")
    warnings = []
    if runs_on_this_machine(address):
        warnings.append(f"the Ray cluster at {address} runs on this machine: the reward functions of console jobs "
                        "run in its worker processes, outside the sandbox, as the user who started Ray. Use a "
                        "cluster of other machines (or another, unprivileged user) when users are not trusted.")
    return warnings


def job_worker_count(requested: int | None, cluster: RayCluster | None, episodes: int) -> int:
    """The rollout workers of a training job: what the request asks (1..the console's count), else
    the console's count (at most one per episode of an iteration), or 1 without a cluster."""
    if cluster is None:
        if requested is not None and requested > 1:
            raise JobError(f"workers: {requested} rollout workers need a Ray cluster, and this console runs its jobs "
                           "in one process each (start it with `laplab serve --ray-address ray://HEAD:10001`)")
        return 1
    if requested is None:
        return max(1, min(cluster.workers, episodes))
    if requested > cluster.workers:
        raise JobError(f"workers: this console gives a job at most {cluster.workers} rollout workers "
                       f"(laplab serve --rollout-workers), the request asks for {requested}")
    if requested > episodes:
        raise JobError(f"workers: {requested} rollout workers is more than the {episodes} episodes of an iteration "
                       "(hyperparameter num_episodes_between_training): every worker needs at least one")
    return requested


def job_workers(cluster: dict, say: Callable[[str], None] = print, watch=None):
    """How a console job's rollout workers start on ``cluster`` (the job spec's ``cluster``: address,
    workers), as a :class:`laplab.cluster.launch.RayWorkers` for the job's ``create_training`` /
    ``resume_training`` (the job's ``config.workers`` of them): their start and restarts go to
    ``say`` (the job log; restarts also to the model folder's ``logs/workers.log``); ``watch`` (a
    :class:`laplab.reward.watchdog.WatchdogLimits`) limits their reward calls as the job's own."""
    from laplab.cluster.launch import RayWorkers
    timeouts = {} if watch is None else {"reward_timeout_s": watch.timeout_s,
                                         "reward_wait_timeout_s": watch.wait_timeout_s}
    return RayWorkers(cluster["address"], notify=say, announce=say, **timeouts)
