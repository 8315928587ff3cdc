"""torch_threads: a temporary torch thread count, restored even on error."""

import pytest
import torch

from legoh_rl.envs.threads import torch_threads


def test_sets_and_restores_the_thread_count():
    before = torch.get_num_threads()
    with torch_threads(2):
        assert torch.get_num_threads() == 2
    assert torch.get_num_threads() == before
    with pytest.raises(RuntimeError), torch_threads(2):
        raise RuntimeError("inside")
    assert torch.get_num_threads() == before


@pytest.mark.parametrize("bad", [0, -1, 1.5, None])
def test_rejects_bad_counts(bad):
    with pytest.raises(ValueError, match=repr(bad)), torch_threads(bad):
        pass
