"""The weights' moving average behind ``checkpoint.ema_decay``: its arithmetic on hand-made
weights, its checks, and a unified run with it that trains exactly as one without it."""

import importlib
import json
import sys
from pathlib import Path

import pytest
import torch
from torch import nn

from legoh_rl.training.checkpoint import (
    CheckpointError,
    export_policy,
    load_checkpoint,
    save_checkpoint,
)
from legoh_rl.training.weight_average import PolicyAverage, saved_average

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_unified import teacher, tiny  # noqa: E402, F401  (the module-scoped tiny oracle)

RECIPES = Path(__file__).resolve().parents[1] / "recipes"
sys.path.insert(0, str(RECIPES))
import unified  # noqa: E402


def _linear(value: float) -> nn.Linear:
    net = nn.Linear(1, 1)
    with torch.no_grad():
        net.weight.fill_(value)
        net.bias.fill_(-value)
    return net


def test_the_average_follows_the_ema_rule_by_hand():
    net, bn = _linear(1.0), nn.BatchNorm1d(1)
    avg = PolicyAverage({"actor": net, "norm": bn}, decay=0.9)
    assert avg.count == 0 and torch.equal(avg.policy_state()["actor"]["weight"], net.weight)  # raw until updated
    avg.update()  # the first update copies
    with torch.no_grad():
        net.weight.fill_(3.0)
        net.bias.fill_(-3.0)
        bn.running_mean.fill_(10.0)
    avg.update()  # 0.9 * 1 + 0.1 * 3 = 1.2; buffers too: 0.9 * 0 + 0.1 * 10 = 1
    state = avg.policy_state()
    assert avg.count == 2
    assert state["actor"]["weight"].item() == pytest.approx(1.2) and state["actor"]["bias"].item() == pytest.approx(-1.2)
    assert state["norm"]["running_mean"].item() == pytest.approx(1.0)
    assert net.weight.item() == 3.0, "the trained weights are never touched"
    # a saved average continues exactly; another decay is refused, naming both
    again = PolicyAverage({"actor": _linear(0.0), "norm": nn.BatchNorm1d(1)}, decay=0.9)
    again.load_state_dict(avg.state_dict())
    assert again.count == 2 and again.policy_state()["actor"]["weight"].item() == pytest.approx(1.2)
    with pytest.raises(ValueError, match="decay 0.9, this run's checkpoint.ema_decay is 0.5"):
        PolicyAverage({"actor": _linear(0.0), "norm": nn.BatchNorm1d(1)}, decay=0.5).load_state_dict(avg.state_dict())


@pytest.mark.parametrize("decay", [0, 1, 1.5, -0.1, True, "0.9"])
def test_a_decay_outside_the_open_unit_interval_is_refused(decay):
    with pytest.raises(ValueError, match=r"checkpoint.ema_decay must be a number in \(0, 1\)"):
        PolicyAverage({"actor": _linear(0.0)}, decay=decay)


def test_export_refuses_weights_for_an_entry_the_checkpoint_lacks(tmp_path):
    save_checkpoint(tmp_path / "last.pt", {"meta": {"kind": "student"}, "actor": {"w": torch.zeros(1)}})
    with pytest.raises(CheckpointError, match="holds no 'perception' weights"):
        export_policy(tmp_path / "last.pt", tmp_path / "slim.pt", weights={"perception": {}})


def test_a_run_with_the_average_trains_exactly_as_without_and_snapshots_it(teacher, tmp_path):  # noqa: F811
    common = ["collector.total_frames=120", "checkpoint.snapshot_every=1", "dagger_iters=10"]
    unified.train(tiny(teacher, tmp_path / "plain", *common))
    unified.train(tiny(teacher, tmp_path / "ema", *common, "checkpoint.ema_decay=0.5"))
    timing = ("_s", "fps_total")  # wall-clock figures differ run to run
    logs = [[{k: v for k, v in json.loads(line).items() if not k.endswith(timing)}
             for line in (tmp_path / run / "metrics.jsonl").read_text().splitlines()] for run in ("plain", "ema")]
    assert logs[0] == logs[1], "the average reads the weights only: the same losses, returns and curriculum"
    plain, ema = load_checkpoint(tmp_path / "plain" / "last.pt"), load_checkpoint(tmp_path / "ema" / "last.pt")
    for key in ("perception", "actor"):
        assert all(torch.equal(plain[key][k], ema[key][k]) for k in plain[key])
    raw = load_checkpoint(tmp_path / "ema" / "snapshots" / "frames000000120.pt")
    avg = load_checkpoint(tmp_path / "ema" / "snapshots" / "ema" / "frames000000120.pt")
    assert avg["meta"]["weights"] == "ema 0.5" and "optim" not in avg
    # three iterations at decay 0.5: w1 / 4 + w2 / 4 + w3 / 2, which differs from w3
    assert any(not torch.equal(raw["actor"][k], avg["actor"][k]) for k in raw["actor"] if raw["actor"][k].is_floating_point())
    assert not (tmp_path / "plain" / "snapshots" / "ema").exists()
    # the resumed average continues from the checkpoint's, not from the current weights
    assert ema["weight_average"]["decay"] == 0.5 and int(ema["weight_average"]["state"]["n_averaged"]) == 3
    again = unified.train(tiny(teacher, tmp_path / "ema", "collector.total_frames=160", "checkpoint.snapshot_every=1",
                               "dagger_iters=10", "checkpoint.ema_decay=0.5", "checkpoint.resume=auto"))
    assert again["iteration"] == 4
    assert int(load_checkpoint(tmp_path / "ema" / "last.pt")["weight_average"]["state"]["n_averaged"]) == 4


def test_the_run_end_is_snapshotted_and_its_saved_average_exports(teacher, tmp_path):  # noqa: F811
    # three iterations of 40 frames, snapshots every 2: iteration 2 by the schedule, 3 as the run's end
    unified.train(tiny(teacher, tmp_path / "run", "collector.total_frames=120", "checkpoint.snapshot_every=2",
                       "dagger_iters=10", "checkpoint.ema_decay=0.5"))
    snaps = tmp_path / "run" / "snapshots"
    assert sorted(p.name for p in snaps.glob("*.pt")) == ["frames000000080.pt", "frames000000120.pt"]
    assert sorted(p.name for p in (snaps / "ema").glob("*.pt")) == ["frames000000080.pt", "frames000000120.pt"]
    end = load_checkpoint(snaps / "ema" / "frames000000120.pt")
    # the training checkpoint's saved average, exported afterwards, is that same end snapshot
    exported = load_checkpoint(export_policy(tmp_path / "run" / "last.pt", tmp_path / "avg.pt", average=True))
    assert exported["meta"]["weights"] == "ema 0.5"
    for key in ("perception", "actor"):
        assert sorted(exported[key]) == sorted(end[key])
        assert all(torch.equal(exported[key][k], end[key][k]) for k in end[key])
    # the recipe's command line: --weights average writes the same file
    argv = sys.argv
    try:
        sys.argv = ["export_policy.py", str(tmp_path / "run" / "last.pt"), str(tmp_path / "cli.pt"), "--weights", "average"]
        importlib.import_module("export_policy").main()
    finally:
        sys.argv = argv
    cli = load_checkpoint(tmp_path / "cli.pt")
    assert cli["meta"]["weights"] == "ema 0.5" and all(torch.equal(cli["actor"][k], end["actor"][k]) for k in end["actor"])
    raw = load_checkpoint(tmp_path / "run" / "last.pt")
    assert any(not torch.equal(raw["actor"][k], exported["actor"][k]) for k in raw["actor"]
               if raw["actor"][k].is_floating_point()), "the average, not the raw weights"
    # a slim policy carries no average: refused, naming the file
    with pytest.raises(CheckpointError, match="avg.pt holds no weight average"):
        export_policy(tmp_path / "avg.pt", tmp_path / "again.pt", average=True)
    with pytest.raises(CheckpointError, match="weights or average, not both"):
        export_policy(tmp_path / "run" / "last.pt", tmp_path / "x.pt", weights={}, average=True)


def test_saved_average_splits_the_averaged_model_by_network_key():
    avg = PolicyAverage({"actor": _linear(2.0), "perception": _linear(5.0)}, decay=0.5)
    assert saved_average({"weight_average": avg.state_dict()}) is None, "no update yet: no average"
    avg.update()
    got = saved_average({"weight_average": avg.state_dict()})
    assert set(got) == {"actor", "perception"} and set(got["actor"]) == {"weight", "bias"}
    assert got["actor"]["weight"].item() == 2.0 and got["perception"]["bias"].item() == -5.0
    assert saved_average({}) is None
