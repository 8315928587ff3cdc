"""A check shared by the multi-process and Ray collection tests."""

import numpy as np


def check_mirrored_workers(saved: dict, workers: int, global_steps: int) -> None:
    """``saved`` (a checkpoint) holds ``workers`` workers' env states, and the main env mirrors them:
    curriculum levels concatenated in worker order, step counters in lockstep."""
    states = saved["env"]["workers"]
    assert len(states) == workers and all("torch_rng" in w for w in states)
    levels = np.concatenate([w["curriculum"]["levels"] for w in states])
    assert np.array_equal(saved["env"]["curriculum"]["levels"], levels)
    assert saved["env"]["global_steps"] == states[0]["global_steps"] == global_steps
