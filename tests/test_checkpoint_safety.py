"""Checkpoints are safe to share and fail with names (issue 50, parts 1, 3, 5, 6).

A code-running pickle is refused by every loader before its payload runs; the committed
checkpoints (and the run states written before the weights-only rule) still load and resume; new
checkpoints need no numpy globals; NaN weights are refused with the tensor named; a full disk at a
checkpoint names the file and what to do and leaves the previous one intact; evaluate.py's numeric
keys are refused with their names.
"""

import errno
import importlib.util
import os
import random
import re
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from hydra import compose, initialize_config_dir

from legoh_rl.training.checkpoint import (
    CheckpointError,
    CheckpointWriteError,
    export_policy,
    load_checkpoint,
    rng_state,
    save_checkpoint,
    set_rng_state,
)

ROOT = Path(__file__).resolve().parents[1]
RECIPES = ROOT / "recipes"
sys.path.insert(0, str(RECIPES))

import oracle_ppo  # noqa: E402

from legoh_rl.paper_tables import read_info  # noqa: E402
from legoh_rl.training import eval_run  # noqa: E402


def cfg_of(name, overrides):
    with initialize_config_dir(config_dir=str(RECIPES / "config"), version_base=None):
        return compose(config_name=name, overrides=overrides)


def recipe_module(name):
    """A recipe as a module under another name (``export_policy`` is also a function's name)."""
    spec = importlib.util.spec_from_file_location(f"{name}_recipe", RECIPES / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


class RunsCode:
    """An object whose pickle calls ``os.system`` when loaded: a shared file's attack."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):
        return (os.system, (f"touch {self.marker}",))


def code_running_checkpoint(path: Path, marker: Path) -> Path:
    """A small oracle-looking checkpoint whose pickle would create ``marker``."""
    torch.save({"meta": {"kind": "oracle", "robot": "h1"}, "networks": {"w": torch.zeros(2)},
                "payload": RunsCode(marker)}, path)
    return path


# -- 1. a code-running pickle is refused, its payload never run -----------------------------------

def test_the_crafted_file_does_run_code_when_unpickled_unsafely(tmp_path):
    """The attack is real: with weights_only=False the pickle runs its command (the refusals
    below are what stop it)."""
    marker = tmp_path / "ran"
    torch.load(code_running_checkpoint(tmp_path / "evil.pt", marker), weights_only=False)
    assert marker.exists()


def _evaluate(path, tmp_path):
    return eval_run.evaluate(cfg_of("evaluate", [
        f"checkpoint={path}", f"output_dir={tmp_path / 'eval'}", "video=false", "logger.backend=csv",
        "categories=[randommix]", "levels=[0]", "robots_per_cell=1", "variants=1", "num_threads=1"]))


def _export_recipe(path, tmp_path, fmt, monkeypatch):
    dst = tmp_path / ("out.onnx" if fmt == "onnx" else "out.pt")
    monkeypatch.setattr(sys, "argv", ["export_policy.py", str(path), str(dst), "--format", fmt])
    recipe_module("export_policy").main()


def _teacher(path, tmp_path):
    from legoh_rl.training.distill import Teacher

    return Teacher(str(path), robot="h1")


def _load_policy(path, tmp_path):
    from legoh_rl.training.evaluation import EvalProtocol
    from legoh_rl.training.policies import load_policy

    return load_policy(str(path), EvalProtocol(categories=("randommix",), levels=(0,), robots_per_cell=1))


LOADERS = {
    "load_checkpoint": lambda path, tmp_path, mp: load_checkpoint(path),
    "evaluate.py": lambda path, tmp_path, mp: _evaluate(path, tmp_path),
    "policies.load_policy": lambda path, tmp_path, mp: _load_policy(path, tmp_path),
    "distill.Teacher": lambda path, tmp_path, mp: _teacher(path, tmp_path),
    "export_policy.py": lambda path, tmp_path, mp: _export_recipe(path, tmp_path, "pt", mp),
    "export_policy.py --format onnx": lambda path, tmp_path, mp: _export_recipe(path, tmp_path, "onnx", mp),
    "checkpoint.export_policy": lambda path, tmp_path, mp: export_policy(path, tmp_path / "slim.pt"),
    "oracle_ppo checkpoint.init": lambda path, tmp_path, mp: oracle_ppo.init_networks(None, None, str(path)),
    "paper_tables.read_info": lambda path, tmp_path, mp: read_info(path),
}


@pytest.mark.parametrize("loader", list(LOADERS))
def test_a_code_running_checkpoint_is_refused_by_every_loader(tmp_path, monkeypatch, loader):
    if loader.endswith("onnx"):
        pytest.importorskip("onnxruntime")
    marker = tmp_path / "pwned"
    evil = code_running_checkpoint(tmp_path / "shared.pt", marker)
    with pytest.raises(CheckpointError, match=rf"{re.escape(str(evil))} refused: loading it would build or call "
                                              r"\S*system") as err:
        LOADERS[loader](evil, tmp_path, monkeypatch)
    assert "Nothing in it was run" in str(err.value)
    assert not marker.exists()  # the payload never ran
    assert not (tmp_path / "slim.pt").exists() and not (tmp_path / "out.pt").exists()


def test_numpy_arrays_beyond_the_legacy_two_stay_refused(tmp_path):
    """The allow-list lets through the int64 and uint32 arrays old run states hold, nothing else:
    an object array (which could hold anything) or a float64 array is refused, named."""
    for array, name in ((np.array([1, "x"], dtype=object), "ObjectDType"), (np.arange(3.0), "Float64DType")):
        path = tmp_path / f"{name}.pt"
        torch.save({"meta": {}, "extra": array}, path)
        with pytest.raises(CheckpointError, match=rf"{re.escape(str(path))} refused: .* call \S*{name}"):
            load_checkpoint(path)


# -- the committed checkpoints, old run states, and what is written now ----------------------------

COMMITTED = sorted((ROOT / "checkpoints").rglob("*.pt"))


def test_every_committed_checkpoint_loads_with_weights_only():
    assert len(COMMITTED) >= 7  # checkpoints/*.pt and checkpoints/ablations/*.pt
    for path in COMMITTED:
        state = load_checkpoint(path)
        assert state["meta"]["kind"] in ("oracle", "student"), path
        assert torch.serialization.get_unsafe_globals_in_checkpoint(path) == [], path  # no allow-list needed


def test_a_run_state_written_before_the_rule_loads_and_resumes_its_random_streams(tmp_path):
    """What run states held until now (np.random.get_state()'s tuple, numpy curriculum levels)
    loads through the allow-list, and its numpy stream restores exactly."""
    np.random.seed(3)
    old = {"meta": {"kind": "oracle"}, "env": {"curriculum": {"levels": np.arange(6, dtype=np.int64)}},
           "rng": {"torch": torch.get_rng_state(), "numpy": np.random.get_state(), "python": random.getstate()}}
    expected = np.random.rand(4)
    torch.save(old, tmp_path / "last.pt")
    assert torch.serialization.get_unsafe_globals_in_checkpoint(tmp_path / "last.pt")  # numpy's globals in it
    state = load_checkpoint(tmp_path / "last.pt")
    np.random.seed(99)
    set_rng_state(state["rng"])
    assert np.array_equal(np.random.rand(4), expected)
    assert np.array_equal(state["env"]["curriculum"]["levels"], np.arange(6))


def test_a_committed_run_state_loads_and_restores(tmp_path):
    path = ROOT / "runs" / "oracle_h1_pit_rungs" / "last.pt"
    if not path.is_file():
        pytest.skip(f"{path} is not in this checkout")
    state = load_checkpoint(path)
    set_rng_state(state["rng"])
    assert isinstance(state["env"]["curriculum"]["levels"], np.ndarray) and state["frames"] > 0


def test_new_checkpoints_need_no_allow_list_and_keep_every_value(tmp_path):
    """save_checkpoint stores numpy arrays as tensors and numpy scalars as numbers; the RNG state
    round-trips exactly (torch, numpy, python); a state_dict keeps its metadata."""
    weights = torch.nn.Linear(2, 2).state_dict()
    levels = np.array([0, 3, 1], dtype=np.int64)
    payload = {"meta": {"kind": "oracle", "gain": np.float32(0.5)}, "networks": weights, "rng": rng_state(),
               "env": {"curriculum": {"levels": levels}, "workers": [{"levels": levels[:2], "key": np.uint32(7)}],
                       "pair": (np.arange(2, dtype=np.uint32), "x")}}
    draws = (torch.rand(3), np.random.rand(3), [random.random() for _ in range(3)])
    path = save_checkpoint(tmp_path / "last.pt", payload)
    assert torch.serialization.get_unsafe_globals_in_checkpoint(path) == []
    state = torch.load(path, weights_only=True)  # no allow-list at all
    env = state["env"]
    assert torch.equal(env["curriculum"]["levels"], torch.tensor([0, 3, 1]))
    assert torch.equal(env["workers"][0]["levels"], torch.tensor([0, 3])) and env["workers"][0]["key"] == 7
    assert env["pair"][0].dtype == torch.uint32 and env["pair"][1] == "x" and isinstance(env["pair"], tuple)
    assert state["meta"]["gain"] == 0.5 and type(state["meta"]["gain"]) is float
    assert isinstance(payload["env"]["curriculum"]["levels"], np.ndarray)  # the caller's payload is untouched
    assert hasattr(state["networks"], "_metadata") and torch.equal(state["networks"]["weight"], weights["weight"])
    set_rng_state(state["rng"])
    assert torch.equal(torch.rand(3), draws[0]) and np.array_equal(np.random.rand(3), draws[1])
    assert [random.random() for _ in range(3)] == draws[2]


def test_a_payload_that_would_not_load_is_refused_at_save_and_the_last_file_kept(tmp_path):
    path = save_checkpoint(tmp_path / "last.pt", {"meta": {}, "frames": 1})
    with pytest.raises(CheckpointError, match=r"save_checkpoint\(.*last.pt\): the payload holds \['pathlib\.\w*Path'\]"):
        save_checkpoint(path, {"meta": {}, "frames": 2, "where": Path("/x")})
    assert load_checkpoint(path)["frames"] == 1 and [p.name for p in tmp_path.iterdir()] == ["last.pt"]


# -- 3. non-finite weights --------------------------------------------------------------------------

@pytest.mark.parametrize("source, key, value", [("oracle_h1.pt", "networks", float("nan")),
                                                ("student_h1.pt", "actor", float("inf"))])
def test_a_checkpoint_with_a_non_finite_weight_is_refused_naming_the_tensor(tmp_path, source, key, value):
    state = load_checkpoint(ROOT / "checkpoints" / source)
    name = [n for n, t in state[key].items() if t.is_floating_point() and t.dim() == 2][1]
    state[key][name][0, 1] = value
    bad = save_checkpoint(tmp_path / "bad.pt", state)
    message = (rf"{re.escape(str(bad))}: weight {re.escape(key + '.' + name)} holds 1 non-finite value\(s\) "
               r"\(NaN or inf\).*Use an earlier checkpoint")
    with pytest.raises(CheckpointError, match=message):
        load_checkpoint(bad)
    with pytest.raises(CheckpointError, match=message):  # the evaluation's loader, before any env is built
        _load_policy(bad, tmp_path)


# -- 5. a full disk at a checkpoint -----------------------------------------------------------------

def _full_disk(*args, **kwargs):
    raise OSError(errno.ENOSPC, "No space left on device")


def _torch_writer_fails(*args, **kwargs):
    raise RuntimeError("[enforce fail at inline_container.cc:664] . PytorchStreamWriter failed writing file "
                       "data/3: file write failed")


FAILURES = {"torch.save ENOSPC": (torch, "save", _full_disk), "os.fsync ENOSPC": (os, "fsync", _full_disk),
            "torch zip writer": (torch, "save", _torch_writer_fails)}


@pytest.mark.parametrize("failure", list(FAILURES))
def test_a_full_disk_names_the_file_and_keeps_the_previous_checkpoint(tmp_path, monkeypatch, failure):
    path = save_checkpoint(tmp_path / "ck" / "last.pt", {"meta": {}, "frames": 64})
    target, name, fail = FAILURES[failure]
    monkeypatch.setattr(target, name, fail)
    with pytest.raises(CheckpointWriteError) as err:
        save_checkpoint(path, {"meta": {}, "frames": 128})
    text = str(err.value)
    assert isinstance(err.value, OSError) and isinstance(err.value, CheckpointError)
    assert f"could not write the checkpoint {path}" in text
    assert f"the previous checkpoint at {path} is intact" in text and "checkpoint.resume=auto" in text
    if failure == "torch zip writer":
        assert "PytorchStreamWriter" in text and err.value.errno == errno.EIO
    else:
        assert err.value.errno == errno.ENOSPC and f"free space in {path.parent} (" in text and "MB free" in text
    monkeypatch.undo()
    assert load_checkpoint(path)["frames"] == 64 and [p.name for p in path.parent.iterdir()] == ["last.pt"]


def test_a_failed_first_write_says_there_was_no_checkpoint_and_other_errors_pass_through(tmp_path, monkeypatch):
    monkeypatch.setattr(torch, "save", _full_disk)
    with pytest.raises(CheckpointWriteError, match=rf"{re.escape(str(tmp_path / 'last.pt'))} .*no earlier checkpoint"):
        save_checkpoint(tmp_path / "last.pt", {"meta": {}})

    def bug(*args, **kwargs):
        raise RuntimeError("not a disk problem")

    monkeypatch.setattr(torch, "save", bug)
    with pytest.raises(RuntimeError, match="^not a disk problem$"):  # not mistaken for a full disk
        save_checkpoint(tmp_path / "last.pt", {"meta": {}})
    assert list(tmp_path.iterdir()) == []


# -- 6. evaluate.py's numeric keys --------------------------------------------------------------------

@pytest.mark.parametrize("override, message", [
    ("trail_seeds=[abc]", "trail_seeds must be a list of integers, got ['abc']: 'abc' is not an integer"),
    ("trail_seeds=[0,1.5]", "trail_seeds must be a list of integers, got [0, 1.5]: 1.5 is not an integer"),
    ("trail_seeds=7", "trail_seeds must be a list of integers, got 7"),
    ("seed=abc", "seed must be an integer, got 'abc'"),
    ("robots_per_cell=two", "robots_per_cell must be an integer, got 'two'"),
    ("runs=true", "runs must be an integer, got True"),
    ("levels=[0,x]", "levels must be a list of integers, got [0, 'x']: 'x' is not an integer"),
    ("variants=2.5", "variants must be an integer, got 2.5"),
    ("video_seconds=long", "video_seconds must be a number, got 'long'"),
])
def test_evaluate_names_the_key_of_a_bad_number_before_any_work(tmp_path, monkeypatch, override, message):
    called = []
    monkeypatch.setattr(eval_run, "load_policy", lambda *a, **k: called.append(1))
    cfg = cfg_of("evaluate", ["checkpoint=zero", f"output_dir={tmp_path / 'eval'}", "logger.backend=csv", override])
    with pytest.raises(ValueError) as err:
        eval_run.evaluate(cfg)
    assert str(err.value) == message
    assert not called and not (tmp_path / "eval").exists()  # refused before any work


def test_evaluate_numbers_accept_what_they_should():
    assert eval_run.number_of("seed", "3") == 3 and eval_run.number_of("variants", 2.0) == 2
    assert eval_run.number_of("video_seconds", 6, float) == 6.0
    assert eval_run.numbers_of("trail_seeds", [0, "1"]) == [0, 1]

