"""Run exported ONNX graphs (:mod:`legoh_rl.training.onnx_export`) as TorchRL policies.

:class:`OnnxModule` is a ``TensorDictModuleBase`` around one onnxruntime session: it reads the
graph's inputs from the TensorDict under the keys its metadata names, and writes its outputs
back, so an exported policy runs in the same benchmark loop as the torch checkpoint:

* oracle: ``OnnxModule(OUT.onnx)`` reads ``proprio, scandots, privileged, expert_goals`` and
  writes ``action`` ``(B, A)``;
* student: ``PerceptionHold(OnnxModule(OUT.perception.onnx))`` runs perception on the worlds
  that tick (10 Hz, or an episode start) and holds its outputs in between, exactly as with the
  torch module; the GRU state ``perception_hidden`` ``(B, L, Hg)`` is carried in the
  TensorDict (a primer) and zeroed where ``is_init``; ``OnnxModule(OUT.locomotion.onnx)`` then
  maps ``z_uni, proprio, delta_g0, goal_next`` (a frozen-oracle RMA student: ``proprio, z_uni,
  priv_latent_uni, goals_uni``) to ``action`` at every step.

``python recipes/evaluate.py checkpoint=OUT.onnx`` evaluates either (:func:`load_onnx_policy`):
``OUT.onnx`` is the oracle's file, or names the student's pair ``OUT.perception.onnx`` +
``OUT.locomotion.onnx`` (either of which may be named too). The env is rebuilt from the meta
block the graphs carry.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import numpy as np
import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase
from torchrl.data import Unbounded
from torchrl.envs import TensorDictPrimer

from legoh_rl.training.builders import eval_env, policy_env_kwargs, policy_meta
from legoh_rl.training.checkpoint import check_meta
from legoh_rl.training.onnx_export import (
    PREFIX,
    DeployError,
    make_session,
    onnx_paths,
)
from legoh_rl.training.student import StudentPolicy, hold_keys, student_env
from legoh_rl.transforms import PerceptionHold

__all__ = ["read_metadata", "resolve_onnx", "OnnxModule", "load_onnx_policy"]


def _key(k):
    return tuple(k) if isinstance(k, list) else k


def read_metadata(path: str | os.PathLike) -> dict:
    """The ``legoh_rl.*`` metadata of an exported graph, decoded: ``meta`` (the checkpoint's meta
    block, ``obs_layout`` shapes as tuples), ``graph``, ``rate_hz``, ``inputs`` / ``outputs``
    (lists of ``(graph name, TensorDict key)``), ``recurrent``, ``files`` (student)...

    Raises:
        FileNotFoundError: no file. DeployError: not a legoh-rl export.
    """
    return _decode(Path(path), _open(path).get_modelmeta().custom_metadata_map)


def _open(path: str | os.PathLike, threads: int = 1):
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"ONNX policy not found: {path}")
    try:
        return make_session(path, threads)
    except ImportError:
        raise
    except Exception as err:  # not an ONNX file, truncated, ...
        raise DeployError(f"{path} is not a readable ONNX graph ({type(err).__name__}: {err})") from None


def _decode(path: Path, props: dict) -> dict:
    if PREFIX + "meta" not in props:
        raise DeployError(f"{path} is not a legoh-rl policy export (no {PREFIX}meta metadata); "
                          "export one with recipes/export_policy.py CKPT OUT.onnx --format onnx")
    out = {k[len(PREFIX):]: v for k, v in props.items() if k.startswith(PREFIX)}
    for k in ("meta", "inputs", "outputs", "recurrent", "files"):
        if k in out:
            out[k] = json.loads(out[k])
    meta = out["meta"]
    meta["obs_layout"] = {k: tuple(v) for k, v in meta.get("obs_layout", {}).items()}
    out["inputs"] = [(n, _key(k)) for n, k in out["inputs"]]
    out["outputs"] = [(n, _key(k)) for n, k in out["outputs"]]
    out["rate_hz"] = float(out.get("rate_hz", "nan"))
    return out


def resolve_onnx(path: str | os.PathLike) -> dict[str, Path]:
    """The graph files a ``checkpoint=`` path names: ``{"oracle": OUT.onnx}`` or
    ``{"perception": ..., "locomotion": ...}``.

    ``OUT.onnx`` names the oracle when that file exists, else the student pair beside it;
    ``OUT.perception.onnx`` / ``OUT.locomotion.onnx`` name their pair (read from the graph's
    ``files`` metadata).

    Raises:
        FileNotFoundError: naming the files looked for.
    """
    path = Path(path)
    if path.is_file():
        info = read_metadata(path)
        if info["graph"] == "oracle":
            return {"oracle": path}
        files = {k: path.parent / v for k, v in info.get("files", {}).items()}
    else:
        files = {k: v for k, v in onnx_paths(path).items() if k != "oracle"}
    missing = [str(p) for p in files.values() if not p.is_file()]
    if not files or missing:
        pair = onnx_paths(path)
        raise FileNotFoundError(f"ONNX policy not found: {path} (looked for {pair['oracle']}, or the student's "
                                f"{pair['perception']} and {pair['locomotion']}; missing {missing or [str(path)]})")
    return files


class OnnxModule(TensorDictModuleBase):
    """One exported graph as a TensorDict module (onnxruntime, CPU).

    ``forward(td)``: every input ``(*batch, *feature)`` is read from ``td`` (float32), the
    batch flattened to ``B``, the graph run, and every output written back as
    ``(*batch, *feature)``. A recurrent state input (``metadata["recurrent"]``) is zeros when
    ``td`` lacks it, and zeroed for the worlds whose ``is_init`` is set; then ``in_keys`` ends
    with ``is_init`` and :meth:`make_tensordict_primer` gives the env its state spec.

    Args:
        path: the ``.onnx`` file. threads: onnxruntime intra-op threads.
    """

    def __init__(self, path: str | os.PathLike, threads: int = 1) -> None:
        super().__init__()
        self.path = Path(path)
        self.session = _open(self.path, threads)
        self.info = _decode(self.path, self.session.get_modelmeta().custom_metadata_map)
        shapes = {i.name: i.shape[1:] for i in self.session.get_inputs()}
        self.feature_shapes = {n: tuple(int(d) for d in shapes[n]) for n in shapes}
        self.inputs = list(self.info["inputs"])
        self.outputs = list(self.info["outputs"])
        self.state_keys = {n: k for n, k in self.inputs if n in self.info.get("recurrent", {})}
        self.in_keys = [k for _, k in self.inputs] + (["is_init"] if self.state_keys else [])
        self.out_keys = [k for _, k in self.outputs]
        names = {n: k for n, k in self.outputs}
        #: per-sample shape of each output, by TensorDict key (the graph's batch axis dropped)
        self.output_shapes = {names[o.name]: tuple(int(d) for d in o.shape[1:])
                              for o in self.session.get_outputs() if o.name in names}
        if self.state_keys:  # found by torchrl's get_primers_from_module
            self.make_tensordict_primer = self._primer

    def _primer(self) -> TensorDictPrimer:
        """Zeros for the recurrent state, ``(L, Hg)`` per world (as ``GRUModule``'s primer)."""
        specs = {k: Unbounded(shape=self.feature_shapes[n]) for n, k in self.state_keys.items()}
        return TensorDictPrimer(specs, expand_specs=True)

    def run(self, feeds: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """Run the graph on ``{input name: (B, *feature) float32}``; ``{output name: array}``."""
        names = [n for n, _ in self.outputs]
        return dict(zip(names, self.session.run(names, feeds), strict=True))

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        """Read the inputs, run the graph, write the outputs (see the class docstring)."""
        td = tensordict
        lead = tuple(td.batch_size)
        n = math.prod(lead)
        init = td.get("is_init", None) if self.state_keys else None
        feeds = {}
        for name, key in self.inputs:
            x = td.get(key, None)
            if x is None:
                if name not in self.state_keys:
                    raise KeyError(f"{self.path.name}: the TensorDict has no {key!r} (graph input {name!r})")
                feeds[name] = np.zeros((n, *self.feature_shapes[name]), dtype=np.float32)
                continue
            arr = np.ascontiguousarray(x.detach().cpu().reshape(n, *self.feature_shapes[name]).float().numpy())
            if name in self.state_keys and init is not None:
                arr = arr.copy()  # not the TensorDict's own state
                arr[init.reshape(n).cpu().numpy()] = 0.0  # episode start: fresh state
            feeds[name] = arr
        out = self.run(feeds)
        for name, key in self.outputs:
            y = torch.from_numpy(out[name])
            y = y.reshape(*lead, *y.shape[1:])
            td.set(key, y if td.device is None else y.to(td.device))
        return td


def load_onnx_policy(checkpoint: str | os.PathLike, protocol, variants: int = 2, seed: int = 0, num_threads=None,
                     trails=None, threads: int = 1, physics: str = "mujoco", domain_rand: bool = False):
    """``(env, policy, kind)`` for exported graphs, as :func:`~legoh_rl.training.policies.load_policy`
    gives for a ``.pt`` checkpoint: the same eval env (robot, gait clock and, for the student,
    its transforms and state primers) rebuilt from the graphs' meta block, randomised when
    ``domain_rand``.

    Raises:
        ImportError: onnxruntime missing (says what to install). FileNotFoundError: no such
        graph(s). DeployError / ValueError: not an export, or an export that does not fit the env.
    """
    files = resolve_onnx(checkpoint)
    if "oracle" in files:
        module = OnnxModule(files["oracle"], threads)
        meta = module.info["meta"]
        env = eval_env(meta["robot"], protocol, variants, seed, num_threads, trails=trails, physics=physics,
                       domain_rand=domain_rand, **policy_env_kwargs(meta))
        check_meta(meta, policy_meta(env, "oracle"), files["oracle"])
        return env, module, "oracle (onnx)"
    perception = OnnxModule(files["perception"], threads)
    locomotion = OnnxModule(files["locomotion"], threads)
    meta = perception.info["meta"]
    if locomotion.info["meta"] != meta:
        raise DeployError(f"{files['perception']} and {files['locomotion']} come from different checkpoints")
    base = eval_env(meta["robot"], protocol, variants, seed, num_threads, depth="depth" in meta["obs_layout"],
                    trails=trails, physics=physics, domain_rand=domain_rand, **policy_env_kwargs(meta))
    check_meta(meta, {**policy_meta(base, "student"), "perception": meta["perception"], "preset": meta["preset"]},
               files["perception"])
    keys = hold_keys(perception)  # a frozen-oracle (RMA) student's perception also gives priv_latent_uni
    hold = PerceptionHold(perception, hold_keys=keys,
                          out_shapes={k: perception.output_shapes[k] for k in keys})
    history = perception.feature_shapes.get("proprio_history", (10,))[0]
    student = StudentPolicy(perception, hold, locomotion, history)
    return student_env(base, student), student.policy, f"student ({meta['perception']}, onnx)"
