"""Console evaluations on a Ray cluster: with ``laplab serve --ray-address``, an evaluate job (a race
submission's, or the model page's) drives its laps on one of the cluster's nodes, as training jobs'
rollout workers do, so a class larger than one machine races on the cluster.

The job's own process (confined on the console's machine, with the network to reach the cluster)
reads the model from its folder (:func:`laplab.evaluate.trials.prepare_evaluation`), ships the
policy's network and weights, the track, the car and the race to a Ray task, which runs the same
evaluation function as the local path (:func:`laplab.evaluate.trials.run_prepared`) and returns its
result; the job then writes it into the model's folder with :func:`laplab.evaluate.trials.save_evaluation`
(simtrace, metrics, summary, video), exactly as a local evaluation does, so the race's board reads it
the same way. The node needs laplab and its dependencies (the cluster's nodes have them for training).
No reward function runs in an evaluation.

The task yields the node's CPU to trainings' rollout workers as a local evaluation job yields to
trainings (``laplab serve --evaluation-priority``, :mod:`laplab.jobs.priority`): its threads' niceness is
raised by the setting above the Ray worker's own (Ray starts every worker at nice 15, rollout workers
included, so the default 10 reaches the ceiling, 19: about 2.4x less CPU than a rollout worker, not the 9x
of nice 0 against 10), or SCHED_IDLE for ``idle``. Not its session's autogroup: on a node that group
holds the raylet and every worker. The worker process serves only this evaluation's Ray job and ends
with it.
"""

from __future__ import annotations

import os
import time
from typing import Callable

POLL_S = 0.5  # how often the job looks for a stop request while the node drives


def node_facts() -> dict:
    """Where this process runs: ``host``, ``pid``, its niceness ``nice`` and Ray's ``node_id`` /
    ``node_ip`` when in Ray."""
    import socket
    facts = {"host": socket.gethostname(), "pid": os.getpid(), "node_id": None, "node_ip": None,
             "nice": os.getpriority(os.PRIO_PROCESS, 0)}
    try:
        import ray
        if ray.is_initialized():
            facts.update(node_id=ray.get_runtime_context().get_node_id(), node_ip=ray.util.get_node_ip_address())
    except Exception:  # noqa: BLE001 - facts Ray cannot give stay None
        pass
    return facts


def drive_on_node(shipped: dict):
    """The Ray task: rebuild the policy from ``shipped`` (:func:`_shipped`) and run the evaluation at
    ``shipped["priority"]`` below the node's workers; returns ``(EvaluationResult, node_facts())``."""
    from laplab.evaluate.trials import PreparedEvaluation, run_prepared
    from laplab.jobs.priority import apply_priority, job_priority
    apply_priority(job_priority(shipped.get("priority", 0)), autogroup=False)
    from laplab.train.config import TrainConfig
    from laplab.train.policy import policy_from_state
    config = TrainConfig.from_dict(shipped["config"])
    policy = policy_from_state(shipped["model"], None, config, shipped["checkpoint"], shipped["learner_state"],
                               shipped["seed"])
    prepared = PreparedEvaluation(policy, shipped["track"], shipped["vehicle"], shipped["race"], shipped["settings"],
                                  shipped["optimal"], shipped["standing"])
    return run_prepared(prepared), node_facts()


def _shipped(prepared) -> dict:
    """What the node needs: the model's config and learner state (no files), the track, car, race,
    settings and optimal lap times."""
    policy = prepared.policy
    settings = prepared.settings
    return {"model": policy.name, "config": policy.config.to_dict(), "checkpoint": policy.checkpoint,
            "learner_state": policy.learner.state_dict(), "seed": 0 if settings.seed is None else settings.seed,
            "track": prepared.track, "vehicle": prepared.vehicle, "race": prepared.race, "settings": settings,
            "optimal": prepared.optimal, "standing": prepared.standing}


def evaluate_model_on_ray(name: str, settings, address: str | None,
                          say: Callable[[str], None] = lambda message: None,
                          should_stop: Callable[[], bool] = lambda: False, priority: int | str = 0):
    """Evaluate stored model ``name`` under ``settings`` on the Ray cluster at ``address`` (None: a
    local Ray) and keep the evaluation in its folder, as :func:`laplab.evaluate.trials.evaluate_model`
    does; returns ``(result, stamp, facts)``, ``facts`` saying where it drove (:func:`node_facts`).
    A stop request (``should_stop``) cancels the task: an :class:`EvaluationError` then. ``priority``:
    how far below the node's other workers the task runs (:mod:`laplab.jobs.priority`; 0: as they do)."""
    from laplab.cluster.collector import _reason, connect_ray
    from laplab.evaluate.trials import EvaluationError, prepare_evaluation, save_evaluation
    from laplab.train.errors import JobError

    prepared = prepare_evaluation(name, settings)
    started_ray = connect_ray(address, 1)
    import ray
    try:
        say(f"evaluating {settings.trials} lap{'s' if settings.trials != 1 else ''} on the Ray cluster at "
            f"{address or 'a local Ray'}")
        task = ray.remote(num_cpus=1, max_retries=1)(drive_on_node)
        pending = task.remote({**_shipped(prepared), "priority": priority})
        began = time.monotonic()
        while True:
            ready, _ = ray.wait([pending], timeout=POLL_S)
            if ready:
                break
            if should_stop():
                ray.cancel(pending, force=True)
                raise EvaluationError("the evaluation was stopped before its laps ended on the Ray cluster")
        try:
            result, facts = ray.get(pending)
        except (EvaluationError, JobError):
            raise
        except Exception as exc:  # noqa: BLE001 - a node lost or a task error: one paragraph for the job's page
            raise JobError(f"the evaluation failed on the Ray cluster at {address or 'a local Ray'}: {_reason(exc)} "
                           "(the job's log has the details; serve without --ray-address to evaluate on this "
                           "machine)") from None
        say(f"the laps were driven on {facts['host']} (Ray node {facts['node_id'] or '?'}, process {facts['pid']} "
            f"at nice {facts.get('nice', '?')}) in {time.monotonic() - began:.1f} s")
    finally:
        if started_ray:
            ray.shutdown()
    stamp, result = save_evaluation(prepared.policy.folder, result)  # as the local path writes it
    return result, stamp, facts
