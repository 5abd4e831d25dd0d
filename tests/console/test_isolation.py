"""Reward functions are untrusted code: a job (and the validation step) cannot read the console's
database, its secret key, the server's environment or another user's reward function; an infinite
loop or a 20 GB allocation fails its own job and nothing else."""

from __future__ import annotations


import pytest

from laplab.jobs.confinement import JobLimits, bubblewrap_works


TINY = {"num_episodes_between_training": 2, "num_epochs": 3, "batch_size": 32}
pytestmark = pytest.mark.skipif(not bubblewrap_works(), reason="bubblewrap is not usable here (apt-get install bubblewrap)")


def spy_reward(paths: list[str]) -> str:
    """A reward that raises LEAKED if it can read any of ``paths`` (else returns 1.0)."""
    return (f"PATHS = {paths!r}\n"
            "def reward_function(params):\n"
            "    import os\n"
            "    for path in PATHS:\n"
            "        try:\n"
            "            with open(path, 'rb') as f:\n"
            "                data = f.read(64)\n"
            "        except OSError:\n"
            "            continue\n"
            "        raise RuntimeError('LEAKED ' + path)\n"
            "    for key in os.environ:\n"
            "        if 'TOKEN' in key or 'SECRET' in key:\n"
            "            raise RuntimeError('LEAKED env ' + key)\n"
            "    return 1.0\n")


def misbehaving_reward(body: str) -> str:
    """A reward that passes validation (its sweep runs in a forked child of the job, multiprocessing's)
    and runs ``body`` in training, at the job's own process's 21st call."""
    return ("import multiprocessing\n"
            "CALLS = [0]\n"
            "def reward_function(params):\n"
            "    if multiprocessing.parent_process() is None:\n"
            "        CALLS[0] += 1\n"
            "    if CALLS[0] > 20:\n"
            f"        {body}\n"
            "    return 1.0\n")


# CPU seconds per job: a tiny training (start-up, validation sweep, 3-4 s of training) uses ~10-15, the
# infinite loop spins until it reaches this limit
CPU_SECONDS = 25


@pytest.fixture(scope="module")
def confined_console(tmp_path_factory, serve_console):
    with serve_console(tmp_path_factory.mktemp("isolation-home"), workers=3,
                       limits=JobLimits.console(cpu_seconds=CPU_SECONDS)) as running:
        yield running


def test_a_reward_function_cannot_read_the_database_secrets_or_other_users_models(confined_console, make_model):
    console = confined_console
    home = console.app.state.store.path.parent
    make_model("victim-model", reward_source="def reward_function(params):\n    return 0.5  # victim's secret idea\n")
    console.app.state.store.claim_model("victim-model", console.app.state.store.add_user("victim")[0].id)
    import os
    paths = [str(home / "laplab.db"), str(home / "laplab.db-wal"), str(home / "console" / "secret.key"),
             str(home / "models" / "victim-model" / "reward_function.py"), f"/proc/{os.getpid()}/environ"]
    assert (home / "models" / "victim-model" / "reward_function.py").exists()

    from laplab.jobs.validate import validate_confined
    unconfined = validate_confined(spy_reward(paths), None, None, owner=99, sandbox=False)
    assert unconfined["ok"] is False and "LEAKED" in unconfined["errors"][0]["message"]  # the spy works...

    attacker = console.add_user("attacker")
    checked = attacker.post("/api/reward/validate", json={"source": spy_reward(paths)})
    assert checked.json()["ok"] is True, checked.json()  # ...but reads nothing through the console
    created = attacker.post("/api/models", json={"name": "spy", "reward_function": spy_reward(paths),
                                                 "max_time_s": 3, "hyperparameters": TINY})
    assert created.status_code == 201, created.text
    model = console.wait_for(attacker, "spy", ("ready", "failed"), timeout_s=300)
    assert model["status"] == "ready", model.get("error")


def test_an_infinite_loop_and_a_20gb_allocation_fail_their_own_job_alone(confined_console):
    console = confined_console
    user = console.add_user("breaker")
    for name, body in (("looper", "while True: pass"), ("hog", "blob = bytearray(20 * 1024 ** 3); blob[-1] = 1")):
        answer = user.post("/api/models", json={"name": name, "reward_function": misbehaving_reward(body),
                                                "max_time_s": 600, "hyperparameters": TINY})
        assert answer.status_code == 201, answer.text
    good = console.add_user("bystander")
    assert good.post("/api/models", json={"name": "bystander-model", "max_time_s": 4,
                                          "hyperparameters": TINY}).status_code == 201
    hog = console.wait_for(user, "hog", ("failed", "ready"), timeout_s=300)
    assert hog["status"] == "failed" and "MemoryError" in (hog["error"] or "") + (hog["job"]["error"] or ""), hog
    fine = console.wait_for(good, "bystander-model", ("ready", "failed"), timeout_s=300)
    assert fine["status"] == "ready", fine
    looper = console.wait_for(user, "looper", ("failed", "ready"), timeout_s=400)
    assert looper["status"] == "failed" and "CPU" in looper["job"]["error"], looper["job"]
    assert console.admin.get("/api/health").status_code == 200  # the server lives on
