"""Scene tests run on one torch thread (restored afterwards).

The scenes are small: one thread is as fast, and on a shared machine the OpenMP barriers of
several threads cost more than the arithmetic (the app runs on one thread by default too).
"""

import pytest
import torch


@pytest.fixture(autouse=True, scope="module")
def _one_thread():
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)
