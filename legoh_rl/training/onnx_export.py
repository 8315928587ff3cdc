"""Export a policy checkpoint to ONNX graphs for deployment (``pip install legoh-rl[deploy]``).

One graph per rate, every one deterministic (it outputs the action mean ``loc``, which is the
action under ``ExplorationType.DETERMINISTIC``) and with a dynamic batch axis ``B``:

* **oracle** (``kind == "oracle"``), 50 Hz, one file ``OUT.onnx``:
  ``proprio (B, D), scandots (B, 132), privileged (B, P), expert_goals (B, N, 2) -> action (B, A)``
  (scandot and privileged encoders, then the actor MLP).
* **student** (``kind == "student"``), two files beside each other:

  - ``OUT.perception.onnx``, 10 Hz (run on perception ticks only; the locomotion graph reuses
    its outputs in between, as :class:`~legoh_rl.transforms.PerceptionHold` does):
    ``depth_goal_stack (B, T, 1+G, H, W), depth (B, 1, H, W), goal_gps (B, 2),
    waypoint_gps (B, 2), proprio (B, D), perception_hidden (B, L, Hg)
    -> z_uni (B, 32), delta_g0 (B, 2), goals_uni (B, N, 2), perception_hidden_out (B, L, Hg)``.
    The GRU state is explicit: feed ``perception_hidden_out`` back as ``perception_hidden`` on
    the next tick, and zeros at an episode start (the torch module's ``is_init`` reset).
    The inputs are those of the checkpoint's perception network (TC-ViT above; the baselines
    read a subset, or ``proprio_history`` (B, T_h, D), and the feed-forward ones carry no state).
  - ``OUT.locomotion.onnx``, 50 Hz:
    ``z_uni (B, 32), proprio (B, D), delta_g0 (B, 2), goal_next (B, 2) -> action (B, A)``, with
    ``goal_next = goals_uni[:, 0]`` (nearest-goal forwarding).

Every graph carries, as ONNX ``metadata_props`` (strings; JSON where structured):

========================  ==================================================================
``legoh_rl.meta``         the checkpoint's meta block (robot, obs_layout, gait fields, kind,
                          perception/preset, experiment, stage): the evaluator rebuilds the
                          same env from it
``legoh_rl.graph``        ``oracle``, ``perception`` or ``locomotion``
``legoh_rl.rate_hz``      the rate the graph runs at (50 or 10)
``legoh_rl.inputs``       ``[[graph input name, TensorDict key], ...]``
``legoh_rl.outputs``      ``[[graph output name, TensorDict key], ...]``
``legoh_rl.recurrent``    ``{state input name: state output name}`` (empty when stateless)
``legoh_rl.files``        ``{"perception": file, "locomotion": file}`` (student; same folder)
``legoh_rl.source``       checkpoint file name, ``legoh_rl.iteration``, ``legoh_rl.frames``
========================  ==================================================================

The graphs are written by torch's TorchScript-based exporter (``torch.onnx.export(...,
dynamo=False)``, opset 17), which needs ``onnx`` only; :func:`export_onnx` then checks each
graph with onnxruntime against the torch modules on sample inputs.
"""

from __future__ import annotations

import json
import os
import warnings
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
import torch
from tensordict.nn import ProbabilisticTensorDictModule, TensorDictModule, TensorDictSequential
from torch import nn
from torchrl.modules import GRUModule

from legoh_rl.modules.configs import PerceptionConfig
from legoh_rl.modules.oracle import make_oracle_actor
from legoh_rl.training.builders import oracle_networks
from legoh_rl.training.checkpoint import load_checkpoint
from legoh_rl.training.student import hold_keys, locomotion_network, student_networks
from legoh_rl.transforms import PerceptionHold

__all__ = [
    "DEPLOY_HINT", "OPSET", "DeployError", "TensorDictGraph", "require_deploy", "onnx_paths", "oracle_graph",
    "student_graphs", "student_modules", "export_onnx", "key_name", "feature_shapes", "sample_inputs", "make_session",
]

OPSET = 17
DEPLOY_HINT = "pip install 'legoh-rl[deploy]'  (or: pip install -e '.[deploy]' in a checkout)"
PREFIX = "legoh_rl."


class DeployError(RuntimeError):
    """A policy that cannot be exported or run as ONNX (the message says why and what to do)."""


def require_deploy(*names: str):
    """Import and return the modules ``names`` (``onnx``, ``onnxruntime``), or raise an
    ``ImportError`` that says which extra to install."""
    mods = []
    for name in names:
        try:
            mods.append(__import__(name))
        except ImportError as err:
            raise ImportError(f"ONNX export and evaluation need the optional packages onnx and onnxruntime "
                              f"({name} is missing: {err}); install them with: {DEPLOY_HINT}") from err
    return mods[0] if len(mods) == 1 else tuple(mods)


def key_name(key) -> str:
    """Graph name of a TensorDict key: ``"proprio"`` as is, ``("next", "h")`` -> ``"h_out"``
    (the state a recurrent graph hands to its next call), other tuples joined by ``.``."""
    if isinstance(key, str):
        return key
    key = tuple(key)
    if len(key) == 2 and key[0] == "next":
        return f"{key[1]}_out"
    return ".".join(key)


def onnx_paths(dst: str | os.PathLike) -> dict[str, Path]:
    """The files of an export named ``dst`` (``OUT.onnx`` or ``OUT``): ``oracle`` ``OUT.onnx``,
    ``perception`` ``OUT.perception.onnx``, ``locomotion`` ``OUT.locomotion.onnx``."""
    dst = Path(dst)
    stem = dst.with_suffix("") if dst.suffix == ".onnx" else dst
    for part in ("perception", "locomotion"):  # OUT.perception.onnx names its pair too
        if stem.suffix == f".{part}":
            stem = stem.with_suffix("")
    return {"oracle": stem.with_name(stem.name + ".onnx"),
            "perception": stem.with_name(stem.name + ".perception.onnx"),
            "locomotion": stem.with_name(stem.name + ".locomotion.onnx")}


# ---------------------------------------------------------------------------------------------- graphs
class TensorDictGraph(nn.Module):
    """A TensorDict module as a plain ``nn.Module`` over positional tensors, for the exporter.

    Walks ``module`` (nested ``TensorDictSequential``/``TensorDictModule`` and torchrl
    ``GRUModule``; the action distribution of a ``ProbabilisticActor`` is skipped, its ``loc``
    is the deterministic action) and runs the same sub-networks in the same order on a dict of
    tensors. ``forward(*inputs)`` takes :attr:`in_keys` in order, each ``(B, *feature)``, and
    returns :attr:`out_keys` in order.

    A ``GRUModule`` runs one step: its state ``key`` ``(B, L, H)`` (the TensorDict layout) is
    an input and ``("next", key)`` an output; ``is_init`` is not read (the caller zeroes the
    state of a world that starts an episode, which is what ``GRUModule`` does with it).

    Args:
        module: the TensorDict module (e.g. the oracle actor, TC-ViT, the locomotion actor).
        out_keys: the keys to return (e.g. ``["loc"]``).

    Raises:
        DeployError: a sub-module of another kind (the causal-transformer memory), or an output
            that no sub-module writes.
    """

    def __init__(self, module: nn.Module, out_keys: Sequence) -> None:
        super().__init__()
        self.steps = nn.ModuleList()
        self.step_keys: list[tuple[str, list, list]] = []
        self._walk(module)
        written: set = set()
        needed: list = []  # keys read before any step writes them: the graph's inputs
        for _, ins, outs in self.step_keys:
            needed += [k for k in ins if k not in written and k not in needed]
            written.update(outs)
        missing = [k for k in out_keys if k not in written]
        if missing:
            raise DeployError(f"{type(module).__name__}: no sub-module writes {missing}")
        self.in_keys = needed
        self.out_keys = list(out_keys)
        self.recurrent = {ins[1]: ("next", ins[1]) for kind, ins, _ in self.step_keys
                          if kind == "gru" and ("next", ins[1]) in self.out_keys}  # state in -> state out

    def _walk(self, m: nn.Module) -> None:
        if isinstance(m, ProbabilisticTensorDictModule):
            return  # the action distribution: the graph stops at loc
        if isinstance(m, GRUModule):
            ins, outs = [_key(k) for k in m.in_keys], [_key(k) for k in m.out_keys]
            self.steps.append(m.gru)
            self.step_keys.append(("gru", ins[:2], outs[:2]))
        elif isinstance(m, TensorDictSequential):
            for sub in m.module:
                self._walk(sub)
        elif isinstance(m, TensorDictModule) and isinstance(m.module, nn.Module):
            self.steps.append(m.module)
            self.step_keys.append(("td", [_key(k) for k in m.in_keys], [_key(k) for k in m.out_keys]))
        else:
            raise DeployError(f"cannot export a {type(m).__name__} to ONNX (supported: TensorDictModule, "
                              "TensorDictSequential, GRUModule; the causal-transformer memory of tcvit_ct is not)")

    def forward(self, *inputs: torch.Tensor) -> tuple[torch.Tensor, ...]:
        """``inputs`` in :attr:`in_keys` order -> the :attr:`out_keys` tensors."""
        values = dict(zip(self.in_keys, inputs, strict=True))
        for step, (kind, ins, outs) in zip(self.steps, self.step_keys, strict=True):
            if kind == "gru":
                x, h = values[ins[0]], values[ins[1]]  # (B, F), (B, L, H)
                y, h_next = step(x.unsqueeze(1), h.transpose(0, 1).contiguous())
                values[outs[0]], values[outs[1]] = y.squeeze(1), h_next.transpose(0, 1)
                continue
            res = step(*(values[k] for k in ins))
            res = res if isinstance(res, tuple) else (res,)
            values.update(zip(outs, res, strict=True))
        return tuple(values[k] for k in self.out_keys)


def _key(k):
    return k if isinstance(k, str) else tuple(k)


def oracle_graph(state: Mapping) -> TensorDictGraph:
    """The oracle of a checkpoint as one graph: ``(proprio, scandots, privileged, expert_goals)
    -> loc`` (shapes in the module docstring)."""
    return TensorDictGraph(make_oracle_actor(oracle_networks(state)), ["loc"]).eval()


def student_modules(meta: Mapping) -> tuple[nn.Module, nn.Module, PerceptionConfig]:
    """``(perception, locomotion actor, perception config)`` of a student checkpoint's meta
    block, untrained (sizes as :func:`~legoh_rl.training.student.make_student` gives them for
    the env the meta block describes)."""
    layout = meta["obs_layout"]
    size = int(layout["depth"][-1]) if "depth" in layout else None  # None: the preset's (a blind student)
    return student_networks(meta["perception"], meta["preset"], int(layout["proprio"][-1]), size,
                            int(layout["expert_goals"][-2]), int(meta["num_actions"]),
                            oracle_config=meta.get("oracle_config"), network=locomotion_network(meta))


def student_graphs(state: Mapping) -> tuple[TensorDictGraph, TensorDictGraph, PerceptionConfig]:
    """``(perception graph, locomotion graph, perception config)`` of a student checkpoint."""
    perception, actor, pcfg = student_modules(state["meta"])
    perception.load_state_dict(state["perception"])
    actor.load_state_dict(state["actor"])
    hold = PerceptionHold(perception, hold_keys=hold_keys(perception))  # what the locomotion module is given
    outs = list(hold.hold_keys) + [("next", k) for k in hold.recurrent_keys]
    return TensorDictGraph(perception, outs).eval(), TensorDictGraph(actor, ["loc"]).eval(), pcfg


def feature_shapes(meta: Mapping, pcfg: PerceptionConfig | None) -> dict:
    """Per-sample shape of every TensorDict key a graph may read (the meta block's
    ``obs_layout``, and the perception inputs and state of ``pcfg``)."""
    layout = {k: tuple(int(x) for x in v) for k, v in meta["obs_layout"].items()}
    shapes = dict(layout)
    if pcfg is not None:
        io = pcfg.io
        shapes.update({
            "depth_goal_stack": (io.num_frames, io.stack_channels, io.image_size, io.image_size),
            "goal_gps": (io.gps_dim,), "waypoint_gps": (io.gps_dim,), "z_uni": (io.latent_dim,),
            "delta_g0": (2,), "goal_next": (2,), "proprio_history": (io.history_len, io.proprio_dim),
            "priv_latent_uni": (io.priv_latent_dim,), "goals_uni": (io.num_goals, 2),
            "perception_hidden": (pcfg.gru_layers, pcfg.gru_hidden),
        })
    return shapes


def sample_inputs(graph: TensorDictGraph, shapes: Mapping, batch: int, seed: int = 0) -> tuple[torch.Tensor, ...]:
    """Random inputs ``(batch, *shape)`` for ``graph`` (standard normal; depth in [0, 1])."""
    gen = torch.Generator().manual_seed(seed)
    out = []
    for k in graph.in_keys:
        if k not in shapes:
            raise DeployError(f"no known shape for the graph input {k!r}")
        x = torch.randn(batch, *shapes[k], generator=gen)
        if k in ("depth", "depth_goal_stack"):
            x = x.abs().clamp(max=1.0)  # normalised depth in [0, 1]
        out.append(x)
    return tuple(out)


# ---------------------------------------------------------------------------------------------- export
def _json_meta(meta: Mapping) -> str:
    def plain(v):
        if isinstance(v, Mapping):
            return {str(k): plain(x) for k, x in v.items()}
        if isinstance(v, (list, tuple)):
            return [plain(x) for x in v]
        if isinstance(v, (np.generic, torch.Tensor)):
            return v.item()
        return v

    return json.dumps(plain(meta), sort_keys=True)


def _export_graph(graph: TensorDictGraph, sample: tuple[torch.Tensor, ...], path: Path, props: Mapping[str, str],
                  doc: str) -> Path:
    onnx = require_deploy("onnx")
    in_names = [key_name(k) for k in graph.in_keys]
    out_names = ["action" if k == "loc" else key_name(k) for k in graph.out_keys]
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    try:
        with warnings.catch_warnings():  # the TorchScript exporter is deprecated in favour of the dynamo one
            warnings.simplefilter("ignore")
            torch.onnx.export(graph, sample, str(tmp), dynamo=False, opset_version=OPSET, input_names=in_names,
                              output_names=out_names, dynamic_axes={n: {0: "batch"} for n in in_names + out_names},
                              do_constant_folding=True)
        _write_metadata(onnx, graph, tmp, in_names, out_names, props, doc)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    return path


def _write_metadata(onnx, graph: TensorDictGraph, tmp: Path, in_names, out_names, props: Mapping[str, str],
                    doc: str) -> None:
    model = onnx.load(str(tmp))
    model.producer_name = "legoh-rl"
    model.doc_string = doc
    del model.metadata_props[:]
    for k, v in props.items():
        entry = model.metadata_props.add()
        entry.key, entry.value = PREFIX + k, str(v)
    entry = model.metadata_props.add()
    entry.key = PREFIX + "inputs"
    entry.value = json.dumps([[n, k] for n, k in zip(in_names, graph.in_keys, strict=True)])
    entry = model.metadata_props.add()
    entry.key = PREFIX + "outputs"
    out_keys = ["action" if k == "loc" else k for k in graph.out_keys]
    entry.value = json.dumps([[n, k] for n, k in zip(out_names, out_keys, strict=True)])
    entry = model.metadata_props.add()
    entry.key = PREFIX + "recurrent"
    entry.value = json.dumps({key_name(k): key_name(v) for k, v in graph.recurrent.items()})
    onnx.checker.check_model(model)
    onnx.save(model, str(tmp))


def make_session(path: str | os.PathLike, threads: int = 1):
    """An onnxruntime CPU ``InferenceSession`` for ``path`` with ``threads`` intra-op threads
    (1 = the caller's thread only, as the evaluation runs torch)."""
    ort = require_deploy("onnxruntime")
    opts = ort.SessionOptions()
    opts.intra_op_num_threads = int(threads)
    opts.inter_op_num_threads = 1
    opts.log_severity_level = 3  # errors only
    return ort.InferenceSession(str(path), sess_options=opts, providers=["CPUExecutionProvider"])


def _max_error(graph: TensorDictGraph, path: Path, sample: tuple[torch.Tensor, ...]) -> float:
    """Largest |onnxruntime - torch| over the graph's outputs on ``sample``."""
    sess = make_session(path)
    names = [i.name for i in sess.get_inputs()]
    got = sess.run(None, {n: x.numpy() for n, x in zip(names, sample, strict=True)})
    with torch.no_grad():
        want = graph(*sample)
    return max(float(np.abs(g - w.numpy()).max()) for g, w in zip(got, want, strict=True))


def export_onnx(src: str | os.PathLike, dst: str | os.PathLike, provenance: Mapping | None = None,
                check_batch: int = 3) -> dict[str, Path]:
    """Export the policy of checkpoint ``src`` as ONNX graph(s) named after ``dst``.

    Args:
        src: a training checkpoint or a slim policy export (``.pt``).
        dst: ``OUT.onnx`` (or ``OUT``): an oracle is written to ``OUT.onnx``, a student to
            ``OUT.perception.onnx`` and ``OUT.locomotion.onnx`` (:func:`onnx_paths`).
        provenance: ``experiment`` / ``stage`` written into the meta block (as
            :func:`~legoh_rl.training.checkpoint.export_policy`).
        check_batch: batch of random inputs on which onnxruntime must reproduce torch.

    Returns:
        ``{graph: path}`` (``oracle``, or ``perception`` and ``locomotion``).

    Raises:
        ImportError: onnx / onnxruntime missing (the message says what to install).
        DeployError: an unknown checkpoint kind, a network the exporter cannot write, or a
            graph whose onnxruntime outputs differ from torch's by more than 1e-4.
    """
    require_deploy("onnx", "onnxruntime")
    state = load_checkpoint(src)
    meta = {**state["meta"], **(provenance or {})}
    kind = meta.get("kind")
    paths = onnx_paths(dst)
    common = {"meta": _json_meta(meta), "source": Path(src).name, "iteration": state.get("iteration", ""),
              "frames": state.get("frames", "")}
    if kind == "oracle":
        graphs = {"oracle": (oracle_graph(state), None, 50)}
    elif kind == "student":
        perception, locomotion, pcfg = student_graphs(state)
        graphs = {"perception": (perception, pcfg, 10), "locomotion": (locomotion, pcfg, 50)}
        common["files"] = json.dumps({k: paths[k].name for k in graphs})
    else:
        raise DeployError(f"{src}: cannot export a checkpoint of kind {kind!r} to ONNX (expected 'oracle' or 'student')")
    docs = {"oracle": "LEGO-H oracle: privileged observations -> action (50 Hz)",
            "perception": "LEGO-H student perception (TC-ViT + GRU): depth history, goal GPS -> z_uni, goals (10 Hz)",
            "locomotion": "LEGO-H student locomotion: z_uni, proprio, goals -> action (50 Hz)"}
    out = {}
    for name, (graph, pcfg, rate) in graphs.items():
        shapes = feature_shapes(meta, pcfg)
        path = _export_graph(graph, sample_inputs(graph, shapes, 1), paths[name],
                             {**common, "graph": name, "rate_hz": rate}, docs[name])
        err = _max_error(graph, path, sample_inputs(graph, shapes, check_batch, seed=1))
        if not err < 1e-4:
            raise DeployError(f"{path}: onnxruntime differs from torch by {err:.3g} on sample inputs")
        out[name] = path
    return out
