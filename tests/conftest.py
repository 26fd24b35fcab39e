"""Suite-wide settings.

torch runs one intra-op thread in the tests: the tensors are tiny, and on a shared
2-core machine two spinning OpenMP threads competing with another job made a 40-step
overfit test take 295 s instead of 8 s. The Warp kernels' own thread split is set per
test where it matters (tests/kernels/conftest.py).
"""

import pytest
import torch


@pytest.fixture(autouse=True, scope="session")
def _one_torch_thread():
    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(previous)
