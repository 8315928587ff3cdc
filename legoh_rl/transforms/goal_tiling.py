"""GoalTiling: the final goal P_B as extra image channel(s) of the depth stack.

Paper (TC-ViT): "The final goal P_B is tiled as an additional (1, H, W) channel ... and fused
at tokenization." This transform encodes a goal vector into one constant-per-band plane of
the depth size and concatenates it to every frame of the depth stack (early fusion).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from tensordict import TensorDictBase
from tensordict.utils import NestedKey
from torchrl.data import Bounded, Composite, Unbounded
from torchrl.envs import Transform

__all__ = ["GoalTiling"]

_ENCODINGS = ("polar", "cartesian")


class GoalTiling(Transform):
    """Tiles goal vector(s) as planes and appends them to each frame of the depth stack.

    **Output.** ``out_key`` (default ``"depth_goal_stack"``) has shape
    ``(*batch, T, 1 + G, H, W)``: channel 0 is the depth frame of ``stack_key``
    (``(*batch, T, H, W)``, e.g. ``depth_stack`` from :class:`DepthHistory`), channels
    ``1..G`` are the planes of the ``G = len(goal_keys)`` goal vectors (default one key,
    ``"goal_gps"``, D_rb in metres in the robot yaw frame). Every frame gets the same, current
    goal planes. The output dtype is the stack's if floating, else ``float32``.

    **Encoding of a 2-D vector into one (H, W) plane.** The plane is split along the width into
    ``K`` equal vertical bands (band ``k`` covers columns ``floor(k W / K)`` to
    ``floor((k + 1) W / K) - 1``, all rows), each band constant:

    * ``encoding="polar"`` (default, needs a 2-D goal): ``K = 3`` bands,
      ``[cos(theta), sin(theta), d / (d + scale)]`` with ``d = |v|`` and
      ``theta = atan2(v_y, v_x)`` (``theta = 0`` when ``d = 0``). Heading is explicit and
      scale-free (the repository's (cos, sin) convention for angles); the distance is squashed
      into ``[0, 1)`` by a softsign, which, unlike ``tanh``, saturates only polynomially, so
      it stays invertible in float32 for far goals (1 km at ``scale = 10`` decodes to ~1e-4
      relative error).
    * ``encoding="cartesian"``: ``K = D`` bands, ``u / (1 + |u|)`` with ``u = v_i / scale``
      (softsign per component); works for any goal dimension ``D``.

    Every value lies in ``[-1, 1]``, the same order of magnitude as normalised depth, and is
    constant over whole columns, so a conv kernel or a 16x16 patch embedding reads it directly
    (each patch sees at most two bands). The encoding is exactly invertible: :meth:`decode`
    averages each band and inverts the softsign (``d = scale * q / (1 - q)``).

    Args:
        goal_keys: goal vector key(s), each ``(*batch, goal_dim)``. Default ``("goal_gps",)``.
        stack_key: depth stack key ``(*batch, T, H, W)``. Default ``"depth_stack"``.
        out_key: output key. Default ``"depth_goal_stack"``.
        encoding: ``"polar"`` (default) or ``"cartesian"``.
        scale: distance scale in the goal's unit (metres), > 0. Default 10.
        goal_dim: length of every goal vector (2; ``"polar"`` requires 2).

    Example:
        >>> env = TransformedEnv(base_env, Compose(DepthHistory(), GoalTiling()))
        >>> td = env.reset()
        >>> td["depth_goal_stack"].shape                  # (num_envs, 4, 2, H, W)
        >>> tiling = env.transform[-1]
        >>> tiling.decode(td["depth_goal_stack"][:, 0, 1])  # == td["goal_gps"] (float32)
    """

    def __init__(
        self,
        goal_keys: NestedKey | Sequence[NestedKey] = ("goal_gps",),
        *,
        stack_key: NestedKey = "depth_stack",
        out_key: NestedKey = "depth_goal_stack",
        encoding: str = "polar",
        scale: float = 10.0,
        goal_dim: int = 2,
    ) -> None:
        if isinstance(goal_keys, (str, tuple)):
            goal_keys = [goal_keys]
        goal_keys = list(goal_keys)
        if not goal_keys:
            raise ValueError("GoalTiling: goal_keys must name at least one goal key, got []")
        if encoding not in _ENCODINGS:
            raise ValueError(f"GoalTiling: encoding must be one of {_ENCODINGS}, got {encoding!r}")
        if isinstance(goal_dim, bool) or not isinstance(goal_dim, int) or goal_dim < 1:
            raise ValueError(f"GoalTiling: goal_dim must be a positive int, got {goal_dim!r}")
        if encoding == "polar" and goal_dim != 2:
            raise ValueError(
                f"GoalTiling: encoding='polar' needs 2-D goals, got goal_dim={goal_dim}; "
                "use encoding='cartesian'"
            )
        scale = float(scale)
        if not scale > 0 or scale == float("inf"):
            raise ValueError(f"GoalTiling: scale must be a finite positive number, got {scale!r}")
        super().__init__(in_keys=[stack_key, *goal_keys], out_keys=[out_key])
        self.stack_key = self.in_keys[0]
        self.goal_keys = self.in_keys[1:]
        self.out_key = self.out_keys[0]
        self.encoding = encoding
        self.scale = scale
        self.goal_dim = goal_dim
        self.num_bands = 3 if encoding == "polar" else goal_dim

    @property
    def num_planes(self) -> int:
        """G: the number of goal planes appended to each frame."""
        return len(self.goal_keys)

    # ------------------------------------------------------------------ encoding
    def _bands(self, width: int, device: torch.device) -> torch.Tensor:
        """Band index of every column, shape ``(width,)``."""
        if width < self.num_bands:
            raise ValueError(
                f"GoalTiling: width {width} is smaller than the {self.num_bands} bands of "
                f"encoding={self.encoding!r}"
            )
        cols = torch.arange(width, device=device)
        return (cols * self.num_bands) // width

    def features(self, goal: torch.Tensor) -> torch.Tensor:
        """Goal ``(..., goal_dim)`` -> band values ``(..., K)`` in ``[-1, 1]``."""
        if goal.shape[-1:] != (self.goal_dim,):
            raise ValueError(
                f"GoalTiling: goal must have shape (..., {self.goal_dim}), got {tuple(goal.shape)}"
            )
        goal = goal if goal.is_floating_point() else goal.float()
        if self.encoding == "polar":
            d = torch.linalg.vector_norm(goal, dim=-1)
            pos = d > 0
            d_safe = torch.where(pos, d, torch.ones_like(d))
            cos = torch.where(pos, goal[..., 0] / d_safe, torch.ones_like(d))
            sin = torch.where(pos, goal[..., 1] / d_safe, torch.zeros_like(d))
            q = d / (d + self.scale)
            return torch.stack([cos, sin, q], -1)
        u = goal / self.scale
        return u / (1 + u.abs())

    def encode(self, goal: torch.Tensor, height: int, width: int) -> torch.Tensor:
        """Goal ``(..., goal_dim)`` -> plane ``(..., height, width)``."""
        if height < 1:
            raise ValueError(f"GoalTiling: height must be >= 1, got {height}")
        feats = self.features(goal)
        row = feats[..., self._bands(width, feats.device)]  # (..., W)
        return row.unsqueeze(-2).expand(*row.shape[:-1], height, width)

    def decode(self, planes: torch.Tensor) -> torch.Tensor:
        """Plane(s) ``(..., H, W)`` -> goal(s) ``(..., goal_dim)``; inverse of :meth:`encode`.

        Any leading dims are kept, e.g. ``decode(x[..., 0, 1:, :, :])`` on a
        ``depth_goal_stack`` gives the ``(..., G, goal_dim)`` goals of the first frame.
        """
        if planes.ndim < 2:
            raise ValueError(
                f"GoalTiling.decode: planes must have shape (..., H, W), got {tuple(planes.shape)}"
            )
        width = planes.shape[-1]
        band = self._bands(width, planes.device)
        col_mean = planes.mean(-2)  # (..., W)
        sums = torch.zeros(*col_mean.shape[:-1], self.num_bands, dtype=col_mean.dtype,
                           device=col_mean.device)
        sums = sums.index_add(-1, band, col_mean)
        counts = torch.bincount(band, minlength=self.num_bands).to(col_mean.dtype)
        feats = sums / counts
        if self.encoding == "polar":
            cos, sin, q = feats.unbind(-1)
            q = q.clamp(0.0, 1.0 - torch.finfo(q.dtype).eps)
            d = self.scale * q / (1 - q)
            norm = torch.sqrt(cos * cos + sin * sin)
            unit = torch.where(norm > 0, d / torch.where(norm > 0, norm, 1.0), torch.zeros_like(d))
            return torch.stack([cos * unit, sin * unit], -1)
        one = 1.0 - torch.finfo(feats.dtype).eps
        feats = feats.clamp(-one, one)
        return self.scale * feats / (1 - feats.abs())

    # ------------------------------------------------------------------ transform
    def _out_dtype(self, dtype: torch.dtype) -> torch.dtype:
        return dtype if dtype.is_floating_point else torch.float32

    def _call(self, next_tensordict: TensorDictBase) -> TensorDictBase:
        td = next_tensordict
        stack = td.get(self.stack_key, None)
        if stack is None:
            raise KeyError(
                f"GoalTiling: stack key {self.stack_key!r} not found (add DepthHistory before "
                f"GoalTiling); available: {sorted(map(str, td.keys(True, True)))}"
            )
        nb = td.batch_dims
        if stack.ndim != nb + 3:
            raise ValueError(
                f"GoalTiling: {self.stack_key!r} must have shape (*batch, T, H, W) with batch "
                f"{tuple(td.batch_size)}, got {tuple(stack.shape)}"
            )
        t, h, w = stack.shape[-3:]
        dtype = self._out_dtype(stack.dtype)
        planes = []
        for key in self.goal_keys:
            goal = td.get(key, None)
            if goal is None:
                raise KeyError(
                    f"GoalTiling: goal key {key!r} not found; available: "
                    f"{sorted(map(str, td.keys(True, True)))}"
                )
            if goal.shape[:nb] != td.batch_size or goal.shape[nb:] != (self.goal_dim,):
                raise ValueError(
                    f"GoalTiling: goal {key!r} must have shape (*batch, {self.goal_dim}) with "
                    f"batch {tuple(td.batch_size)}, got {tuple(goal.shape)}"
                )
            planes.append(self.encode(goal, h, w).to(dtype))
        goal_planes = torch.stack(planes, -3)  # (*batch, G, H, W)
        goal_planes = goal_planes.unsqueeze(-4).expand(*stack.shape[:-3], t, -1, h, w)
        out = torch.cat([stack.to(dtype).unsqueeze(-3), goal_planes], dim=-3)
        td.set(self.out_key, out)
        return td

    def _reset(
        self, tensordict: TensorDictBase | None, tensordict_reset: TensorDictBase
    ) -> TensorDictBase:
        return self._call(tensordict_reset)

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        """Offline use (e.g. as a replay-buffer transform): same as the env step.

        Stateless, so it works on any batch shape, e.g. ``[N, T]`` samples: store
        ``depth_stack`` and the goal, and tile at sampling time to save memory.
        """
        return self._call(tensordict)

    def transform_observation_spec(self, observation_spec: Composite) -> Composite:
        """Add ``out_key``: ``(*batch, T, 1 + G, H, W)``; goal channels bounded in [-1, 1]."""
        keys = set(observation_spec.keys(True, True))
        for key in [self.stack_key, *self.goal_keys]:
            if key not in keys:
                raise KeyError(
                    f"GoalTiling: key {key!r} is not in the observation spec; available: "
                    f"{sorted(map(str, keys))}"
                )
        batch = observation_spec.shape
        nb = len(batch)
        spec = observation_spec[self.stack_key]
        if len(spec.shape) != nb + 3:
            raise ValueError(
                f"GoalTiling: spec of {self.stack_key!r} must be (*batch, T, H, W), got "
                f"{tuple(spec.shape)}"
            )
        for key in self.goal_keys:
            gshape = observation_spec[key].shape
            if tuple(gshape[nb:]) != (self.goal_dim,):
                raise ValueError(
                    f"GoalTiling: spec of goal {key!r} must be (*batch, {self.goal_dim}), got "
                    f"{tuple(gshape)}"
                )
        t, h, w = spec.shape[-3:]
        shape = torch.Size((*batch, t, 1 + self.num_planes, h, w))
        dtype = self._out_dtype(spec.dtype)
        if isinstance(spec, Bounded):
            extra = (*batch, t, self.num_planes, h, w)
            low = torch.cat(
                [spec.space.low.to(dtype).unsqueeze(-3),
                 torch.full(extra, -1.0, dtype=dtype, device=spec.device)], -3
            )
            high = torch.cat(
                [spec.space.high.to(dtype).unsqueeze(-3),
                 torch.full(extra, 1.0, dtype=dtype, device=spec.device)], -3
            )
            out = Bounded(low=low, high=high, shape=shape, dtype=dtype, device=spec.device)
        else:
            out = Unbounded(shape=shape, dtype=dtype, device=spec.device)
        observation_spec[self.out_key] = out
        return observation_spec

    def __repr__(self) -> str:
        return (
            f"{type(self).__name__}(goal_keys={self.goal_keys}, stack_key={self.stack_key!r}, "
            f"out_key={self.out_key!r}, encoding={self.encoding!r}, scale={self.scale})"
        )
