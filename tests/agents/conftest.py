import pytest


@pytest.fixture
def restore_torch_threads():
    """Give torch its thread count back after a test that sets it (learners built with num_threads)."""
    import torch
    previous = torch.get_num_threads()
    yield
    torch.set_num_threads(previous)
