"""Issue 31, bad input: a body the JSON parser gives up on gets a message that says why."""

from fastapi.testclient import TestClient


def test_deeply_nested_body_is_named(tmp_path, monkeypatch):
    monkeypatch.setenv("LAPLAB_HOME", str(tmp_path))
    monkeypatch.setenv("LAPLAB_ADMIN_TOKEN", "admin-test-token-0123456789")
    from laplab.console.app import create_app
    client = TestClient(create_app(workers=1, warm_cache=False))  # no lifespan: no scheduler, no jobs
    headers = {"Authorization": "Bearer admin-test-token-0123456789", "Content-Type": "application/json"}
    body = "[" * 100_000 + "]" * 100_000
    response = client.post("/api/models", content=body, headers=headers)
    assert response.status_code == 400
    detail = response.json()["detail"]
    assert detail["field"] == "body" and "nests arrays or objects deeper" in detail["message"]
    # other HTTP errors keep FastAPI's form
    assert client.get("/api/models/nope", headers=headers).status_code == 404
