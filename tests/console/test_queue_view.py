"""A queued training shows its place in the line and the configuration it will train."""

from __future__ import annotations

TINY = {"num_episodes_between_training": 2, "num_epochs": 3, "batch_size": 32}
REWARD = "def reward_function(params):\n    return 2.0\n"


def test_a_queued_model_shows_its_place_and_its_configuration(tmp_path, serve_console):
    with serve_console(tmp_path, workers=1) as console:
        admin = console.admin
        for name in ("first", "second", "third"):
            body = {"name": name, "track": "oval", "max_time_s": 120 if name == "first" else 7,
                    "hyperparameters": TINY, "reward_function": REWARD, "physics": "5"}
            created = admin.post("/api/models", json=body)
            assert created.status_code == 201, created.text
        try:
            second, third = (admin.get(f"/api/models/{name}").json() for name in ("second", "third"))
            assert second["status"] == third["status"] == "queued"
            assert third["queue_position"] == second["queue_position"] + 1
            config = third["config"]  # the laplab.json the job will write, before it has a folder
            assert config["track"] == "oval" and config["max_time_s"] == 7 and config["vehicle"] == "deepracer-v5"
            assert config["hyperparameters"]["num_epochs"] == 3 and third["reward_function"] == REWARD
        finally:
            for name in ("third", "second", "first"):
                admin.post(f"/api/models/{name}/stop")
