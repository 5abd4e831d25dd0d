"""Model names are per user: two students may both have `my-first-model`, and no answer (a 409, a
404, a list) reveals another user's models. A real server, real training jobs."""

from __future__ import annotations

TINY = {"num_episodes_between_training": 2, "num_epochs": 3, "batch_size": 32}


def _reward(value: float) -> str:
    return f"def reward_function(params):\n    return {value}\n"


def test_two_users_may_have_models_of_the_same_name(tmp_path, serve_console):
    with serve_console(tmp_path, workers=2) as console:
        alice, bob = console.add_user("alice"), console.add_user("bob")
        for client, value in ((alice, 1.0), (bob, 2.0)):
            created = client.post("/api/models", json={"name": "my-first-model", "max_time_s": 5,
                                                       "hyperparameters": TINY, "reward_function": _reward(value)})
            assert created.status_code == 201, created.text
            assert created.json()["name"] == "my-first-model"
        again = bob.post("/api/models", json={"name": "my-first-model", "max_time_s": 5})
        assert again.status_code == 409 and "you already have" in again.json()["detail"]["message"]
        for client, value, owner in ((alice, 1.0, "alice"), (bob, 2.0, "bob")):
            model = console.wait_for(client, "my-first-model", ("ready", "failed"))
            assert model["status"] == "ready", model
            assert model["owner"] == owner and model["reward_function"] == _reward(value)
            assert [m["name"] for m in client.get("/api/models").json()] == ["my-first-model"]
        # bob cannot reach alice's model by any name, and his own names say nothing about hers
        alice_id = console.app.state.store.user_by_name("alice").id
        assert bob.get(f"/api/models/u{alice_id}-my-first-model").status_code == 404
        assert bob.post("/api/models", json={"name": "only-alice-has-this", "max_time_s": 5}).status_code == 201
        listed = {m["name"]: m["owner"] for m in console.admin.get("/api/models").json()}
        keys = [name for name, owner in listed.items() if owner in ("alice", "bob") and name.endswith("my-first-model")]
        assert len(keys) == 2  # the admin sees both, each by its own key
        for key in keys:
            assert console.admin.get(f"/api/models/{key}").status_code == 200
        clone = alice.post("/api/models/my-first-model/clone", json={"name": "my-clone", "max_time_s": 5})
        assert clone.status_code == 201, clone.text
        assert bob.get("/api/models/my-clone").status_code == 404
        bob.post("/api/models/only-alice-has-this/stop")
        alice.post("/api/models/my-clone/stop")
