"""The recipes' ``device``: resolution, device-agnostic checkpoints, env.device not a setting.

Nothing here runs on a GPU (the reference machine has none): the resolution logic is tested with
``torch.cuda`` answers patched, the training on the CPU (tests/test_recipes.py: ``device=cpu`` and
``device=auto`` train identically).
"""

import pytest
import torch

from legoh_rl.training import checkpoint as ckpt
from legoh_rl.training.config_store import env_config
from legoh_rl.training.device import resolve_device


@pytest.fixture
def no_cuda(monkeypatch):
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)


@pytest.fixture
def two_gpus(monkeypatch):  # what torch would answer on a machine with two GPUs (no tensor goes there)
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(torch.cuda, "device_count", lambda: 2)
    monkeypatch.setattr(torch.cuda, "current_device", lambda: 0)


def test_auto_is_the_cpu_without_cuda(no_cuda):
    assert resolve_device("auto") == torch.device("cpu")
    assert resolve_device(None) == torch.device("cpu")
    assert resolve_device("cpu") == torch.device("cpu")
    assert resolve_device(" CPU ") == torch.device("cpu")


@pytest.mark.parametrize("name", ["cuda", "cuda:0", "cuda:3"])
def test_cuda_without_cuda_is_an_error_naming_the_value(no_cuda, name):
    with pytest.raises(ValueError, match=rf"device={name} but no CUDA device"):
        resolve_device(name)


@pytest.mark.parametrize("name", ["gpu", "tpu", "cuda:x", "cuda0", ""])
def test_unknown_values_are_refused_by_name(name):
    with pytest.raises(ValueError, match=rf"device={name!r} is not a device: use one of \['auto', 'cpu', 'cuda'"):
        resolve_device(name)


def test_resolution_with_cuda(two_gpus):
    assert resolve_device("auto") == torch.device("cuda", 0)  # the index, as torchrl's envs name theirs
    assert resolve_device("cuda") == torch.device("cuda", 0)
    assert resolve_device("cuda:1") == torch.device("cuda", 1)
    assert resolve_device("cpu") == torch.device("cpu")
    with pytest.raises(ValueError, match=r"device=cuda:2 but this machine has 2 CUDA device\(s\)"):
        resolve_device("cuda:2")


def test_checkpoints_load_to_the_cpu(tmp_path, monkeypatch):
    """Every load maps to the CPU (a GPU run's checkpoint loads on a machine without one)."""
    path = ckpt.save_checkpoint(tmp_path / "last.pt", {"meta": {"kind": "oracle"}, "networks": {"w": torch.ones(3)},
                                                       "optim": {"state": {0: {"exp_avg": torch.zeros(2)}}}})
    seen = {}
    real = torch.load

    def spy(*args, **kwargs):
        seen.update(kwargs)
        return real(*args, **kwargs)

    monkeypatch.setattr(torch, "load", spy)
    state = ckpt.load_checkpoint(path)
    assert seen["map_location"] == "cpu"
    assert state["networks"]["w"].device == torch.device("cpu") and torch.equal(state["networks"]["w"], torch.ones(3))
    assert state["optim"]["state"][0]["exp_avg"].device == torch.device("cpu")


def test_rng_state_without_cuda_has_no_cuda_entry_and_restores(no_cuda):
    state = ckpt.rng_state()
    assert "cuda" not in state
    a = torch.rand(3)
    ckpt.set_rng_state(state)
    assert torch.equal(torch.rand(3), a)
    ckpt.set_rng_state({**state, "cuda": [torch.zeros(8, dtype=torch.uint8)]})  # a GPU run's, resumed here: ignored
    assert torch.equal(torch.rand(3), a)


def test_env_device_is_not_a_setting_of_the_env_section():
    section = {"robot": "h1", "num_envs": 2, "categories": ["randommix"]}
    assert env_config(section, "oracle").device == "cpu"
    assert env_config(section, "oracle", device="cuda:0").device == "cuda:0"  # the recipe's device
    with pytest.raises(ValueError, match=r"env.device='cuda' is not a setting: it is the recipe's device=\.\.\."):
        env_config({**section, "device": "cuda"}, "oracle")
