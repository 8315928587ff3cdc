"""DepthHistory: the 16-frame depth history, downsampled to 4, gated by the perception tick.

Paper (TC-ViT): "processing 16-frame depth sequences (downsampled to 4)". Depth arrives at
the perception rate (10 Hz) while the env steps at the control rate (50 Hz), so a frame enters
the history only on ``perception_tick`` steps; between ticks the history (and the output
stack) is held.
"""

from __future__ import annotations

import torch
from tensordict import TensorDictBase
from tensordict.utils import NestedKey, unravel_key
from torchrl.data import Bounded, Composite, TensorSpec, Unbounded
from torchrl.envs import Transform

from legoh_rl.transforms._common import batch_flag, expand_right

__all__ = ["DepthHistory"]


class DepthHistory(Transform):
    """Keeps the last ``history`` depth frames per world and outputs every ``stride``-th.

    With the defaults (``history=16, stride=4``) the output ``depth_stack`` has shape
    ``(*batch, 4, H, W)`` and holds, **oldest first, newest last**, the frames that entered
    the history 12, 8, 4 and 0 entries ago. On a stream where frame ``k`` has value ``k`` and
    every step is a tick, the stack at step ``k >= 12`` is exactly ``[k-12, k-8, k-4, k]``.

    **Gating.** A frame enters the history only on steps where ``tick_key`` (a ``(1,)`` bool,
    default ``"perception_tick"``) is True, per world. If the tensordict has no such key (an
    env without a perception rate, or ``tick_key=None``), every step is a tick. Between
    ticks the history of that world is unchanged and the same stack is emitted again.

    **Reset / padding.** On reset (all worlds, or the worlds flagged by the ``"_reset"`` mask
    of a partial reset) the history of each reset world is filled with its first frame after
    reset, as torchrl's ``CatFrames(padding="same")`` does: right after reset the stack is
    ``[f0, f0, f0, f0]``; after ticks ``f1, f2`` it is ``[f0, f0, f1, f2]`` ... The reset
    frame is always taken, whatever the tick flag says. Other worlds are untouched.

    **Shapes.** ``in_key`` is ``(*batch, 1, H, W)`` or ``(*batch, H, W)`` (any dtype; the
    stack keeps it); ``out_key`` is ``(*batch, history // stride, H, W)``. ``in_key`` is kept.
    The output spec copies the input's class: ``Bounded`` bounds are repeated per frame,
    anything else becomes ``Unbounded`` with the same dtype.

    **State.** The history is an internal, non-persistent buffer ``(*batch, history, H, W)``
    (like ``CatFrames``), so nothing large travels in the tensordict.

    **Replay buffers.** Store the *stacks* (``depth_stack``), which is what a Collector
    returns: a stack depends on up to ``(history - 1)`` ticks, i.e. ``5 * 15 = 75`` control
    steps on the 50 Hz / 10 Hz env, far more than a training slice holds, and the per-step
    cost is ``history // stride`` frames, not ``history``. To store single frames instead,
    keep ``depth``, the tick key and ``is_init`` (or ``("next", "done")``) in the buffer and
    call this transform as the buffer's transform: :meth:`forward` rebuilds the stacks of a
    ``[..., T]`` slice (time last) exactly, provided the slice starts at an episode start;
    otherwise the first step of the slice is treated as a reset (history padded with it).

    **Why not torchrl's CatFrames.** ``CatFrames(N=16, dim=-3)`` does the rolling window, the
    "same" padding on partial resets and offline unfolding, and on an env without a tick key
    ``CatFrames(N=16, dim=-3)`` followed by selecting frames ``3, 7, 11, 15`` gives the same
    stacks as this transform (tested). But its step hook rolls its buffer on *every* call, so
    it cannot hold the history on non-tick steps, and its offline unfolding has no notion of
    a tick either; it also outputs all ``N`` frames (a second transform would be needed to
    subsample) and needs an explicit channel dim. Those are what this class adds.

    Args:
        history: number of frames kept (paper: 16).
        stride: keep every ``stride``-th frame, newest included (paper: 16 -> 4, stride 4).
            ``history`` must be divisible by ``stride``.
        in_key: depth frame key. Default ``"depth"``.
        out_key: stack key. Default ``"depth_stack"``.
        tick_key: per-world perception-tick flag; ``None`` (or absent from the data) means
            every step is a tick. Default ``"perception_tick"``.
        reset_key: partial-reset mask key; default: the parent env's only reset key, else
            ``"_reset"``.
        init_key: only used by :meth:`forward` (offline): marks the first step of an episode.
            Default ``"is_init"`` (torchrl's ``InitTracker``).
        done_key: only used by :meth:`forward`: ``("next", done_key)`` at step ``t - 1``
            also marks ``t`` as an episode start. Default ``"done"``.

    Example:
        >>> from torchrl.envs import TransformedEnv, Compose
        >>> env = TransformedEnv(base_env, DepthHistory())        # base_env writes "depth"
        >>> td = env.reset()
        >>> td["depth_stack"].shape                              # (num_envs, 4, H, W)
        >>> # another env: 'pixels' (1, 8, 8), no tick key -> frames enter every step
        >>> DepthHistory(in_key="pixels", out_key="pixels_stack", tick_key=None)
    """

    def __init__(
        self,
        history: int = 16,
        stride: int = 4,
        *,
        in_key: NestedKey = "depth",
        out_key: NestedKey = "depth_stack",
        tick_key: NestedKey | None = "perception_tick",
        reset_key: NestedKey | None = None,
        init_key: NestedKey | None = "is_init",
        done_key: NestedKey | None = "done",
    ) -> None:
        if isinstance(history, bool) or not isinstance(history, int) or history < 1:
            raise ValueError(f"DepthHistory: history must be a positive int, got {history!r}")
        if isinstance(stride, bool) or not isinstance(stride, int) or stride < 1:
            raise ValueError(f"DepthHistory: stride must be a positive int, got {stride!r}")
        if history % stride != 0:
            raise ValueError(
                f"DepthHistory: history={history} is not divisible by stride={stride}; "
                f"choose e.g. history={history - history % stride or stride} for stride {stride}"
            )
        super().__init__(in_keys=[in_key], out_keys=[out_key])
        self.history = history
        self.stride = stride
        self.num_frames = history // stride
        self.in_key = self.in_keys[0]
        self.out_key = self.out_keys[0]
        self.tick_key = tick_key
        self._reset_key = reset_key
        self.init_key = init_key
        self.done_key = done_key
        # offsets back from the newest frame, oldest first: (12, 8, 4, 0) by default
        self.offsets = tuple(stride * (self.num_frames - 1 - i) for i in range(self.num_frames))
        idx = torch.tensor([history - 1 - o for o in self.offsets], dtype=torch.long)
        self.register_buffer("_select", idx, persistent=False)
        self.register_buffer("_history", None, persistent=False)

    # ------------------------------------------------------------------ keys / shapes
    @property
    def reset_key(self) -> NestedKey:
        """The partial-reset mask key (``"_reset"`` unless the parent env says otherwise)."""
        if self._reset_key is not None:
            return self._reset_key
        parent = self.parent
        if parent is not None and len(parent.reset_keys) == 1:
            return parent.reset_keys[0]
        return "_reset"

    def _frame(self, data: torch.Tensor, batch_size: torch.Size, key: NestedKey) -> torch.Tensor:
        """``(*batch, 1, H, W)`` or ``(*batch, H, W)`` -> ``(*batch, H, W)``."""
        nb = len(batch_size)
        feat = tuple(data.shape[nb:])
        if tuple(data.shape[:nb]) == tuple(batch_size):
            if len(feat) == 2 and min(feat) > 0:
                return data
            if len(feat) == 3 and feat[0] == 1 and min(feat) > 0:
                return data.squeeze(nb)
        raise ValueError(
            f"DepthHistory: {key!r} must have shape (*batch, 1, H, W) or (*batch, H, W) with "
            f"batch {tuple(batch_size)}, got {tuple(data.shape)}"
        )

    def _get_frame(self, td: TensorDictBase, key: NestedKey) -> torch.Tensor:
        data = td.get(key, None)
        if data is None:
            raise KeyError(
                f"DepthHistory: depth key {key!r} not found; available keys: "
                f"{sorted(map(str, td.keys(True, True)))}"
            )
        return self._frame(data, td.batch_size, key)

    def _output(self, history: torch.Tensor) -> torch.Tensor:
        # index_select copies: stored outputs never alias the internal buffer
        return history.index_select(-3, self._select.to(history.device))

    # ------------------------------------------------------------------ online hooks
    def _call(self, next_tensordict: TensorDictBase) -> TensorDictBase:
        """Env step: push the new frame for ticking worlds, emit the stack for all."""
        frame = self._get_frame(next_tensordict, self.in_key)
        hist = self._history
        if hist is None or hist.shape[:-3] != frame.shape[:-2] or hist.shape[-2:] != frame.shape[-2:]:
            # no history yet (stepped without reset): behave as a reset
            hist = frame.unsqueeze(-3).expand(*frame.shape[:-2], self.history, *frame.shape[-2:])
            hist = hist.clone()
        else:
            tick = batch_flag(next_tensordict, self.tick_key, next_tensordict.batch_size, "tick")
            if tick is None or bool(tick.all()):
                hist = torch.cat([hist[..., 1:, :, :], frame.unsqueeze(-3).to(hist.dtype)], dim=-3)
            elif bool(tick.any()):
                # only the ticking worlds' histories move (in place: the stored stacks are copies,
                # _output); the others are left untouched rather than rewritten with themselves
                rows = tick.nonzero(as_tuple=True)
                hist[rows] = torch.cat([hist[rows][..., 1:, :, :], frame[rows].unsqueeze(-3).to(hist.dtype)], dim=-3)
        self._history = hist
        next_tensordict.set(self.out_key, self._output(hist))
        return next_tensordict

    def _reset(
        self, tensordict: TensorDictBase | None, tensordict_reset: TensorDictBase
    ) -> TensorDictBase:
        """Env reset: fill the history of the reset worlds with their first frame."""
        frame = self._get_frame(tensordict_reset, self.in_key)
        batch = tensordict_reset.batch_size
        mask = batch_flag(tensordict, self.reset_key, batch, "reset")
        fill = frame.unsqueeze(-3).expand(*frame.shape[:-2], self.history, *frame.shape[-2:])
        hist = self._history
        fresh = (
            hist is None
            or hist.shape[:-3] != frame.shape[:-2]
            or hist.shape[-2:] != frame.shape[-2:]
            or hist.dtype != frame.dtype
        )
        if mask is None or bool(mask.all()):
            hist = fill.clone()
        elif fresh:
            if hist is not None:
                raise ValueError(
                    f"DepthHistory: partial reset with frames of shape {tuple(frame.shape)} but "
                    f"the history holds {tuple(hist.shape)}; do a full reset first"
                )
            hist = fill.clone()  # first reset is partial: every world starts from its frame
        elif bool(mask.any()):  # the reset worlds' rows only, in place (see _call)
            rows = mask.nonzero(as_tuple=True)
            hist[rows] = fill[rows]
        self._history = hist
        tensordict_reset.set(self.out_key, self._output(hist))
        return tensordict_reset

    def _reset_on_native_autoreset(
        self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase
    ) -> TensorDictBase:
        return self._reset(tensordict, tensordict_reset)

    # ------------------------------------------------------------------ specs
    def transform_observation_spec(self, observation_spec: Composite) -> Composite:
        """Add ``out_key``: ``(*batch, history // stride, H, W)``, same class/dtype as depth."""
        if self.in_key not in observation_spec.keys(True, True):
            raise KeyError(
                f"DepthHistory: depth key {self.in_key!r} is not in the observation spec; "
                f"available: {sorted(map(str, observation_spec.keys(True, True)))}"
            )
        spec = observation_spec[self.in_key]
        observation_spec[self.out_key] = self._stack_spec(spec, observation_spec.shape)
        return observation_spec

    def _stack_spec(self, spec: TensorSpec, batch_size: torch.Size) -> TensorSpec:
        nb = len(batch_size)
        feat = tuple(spec.shape[nb:])
        if not (len(feat) == 2 or (len(feat) == 3 and feat[0] == 1)):
            raise ValueError(
                f"DepthHistory: spec of {self.in_key!r} must have shape (*batch, 1, H, W) or "
                f"(*batch, H, W) with batch {tuple(batch_size)}, got {tuple(spec.shape)}"
            )
        h, w = feat[-2:]
        shape = torch.Size((*batch_size, self.num_frames, h, w))
        if isinstance(spec, Bounded):
            low = spec.space.low.reshape(*batch_size, 1, h, w).expand(shape).clone()
            high = spec.space.high.reshape(*batch_size, 1, h, w).expand(shape).clone()
            return Bounded(low=low, high=high, shape=shape, dtype=spec.dtype, device=spec.device)
        return Unbounded(shape=shape, dtype=spec.dtype, device=spec.device)

    # ------------------------------------------------------------------ offline
    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        """Offline: rebuild the stacks of stored trajectories ``[..., T]`` (time last).

        Reads ``in_key`` (``[..., T, 1, H, W]`` or ``[..., T, H, W]``), the tick key (absent:
        every step ticks) and the episode starts (``init_key``, ``("next", done_key)`` of the
        previous step, and always ``t = 0``). Writes ``out_key`` ``[..., T, n, H, W]`` equal to
        what the online transform emitted, and ``("next", out_key)`` when ``("next", in_key)``
        is present. Fully vectorised (no loop over time). Used as a replay-buffer transform;
        it does not touch the online state.
        """
        if tensordict.batch_dims == 0:
            raise ValueError(
                "DepthHistory.forward needs a tensordict with a time dimension (last batch dim), "
                "got batch_size=()"
            )
        batch = tensordict.batch_size
        n_rows = batch[:-1].numel()
        t_len = batch[-1]
        frames = self._get_frame(tensordict, self.in_key)
        hw = frames.shape[-2:]
        frames = frames.reshape(n_rows * t_len, *hw)

        tick = batch_flag(tensordict, self.tick_key, batch, "tick")
        tick = torch.ones(batch, dtype=torch.bool, device=frames.device) if tick is None else tick
        start = torch.zeros(batch, dtype=torch.bool, device=frames.device)
        start[..., 0] = True
        init = batch_flag(tensordict, self.init_key, batch, "init")
        if init is not None:
            start |= init
        done_key = unravel_key(("next", self.done_key)) if self.done_key is not None else None
        done = batch_flag(tensordict, done_key, batch, "done")
        if done is not None and t_len > 1:
            start[..., 1:] |= done[..., :-1]
        tick = tick.reshape(-1)
        start = start.reshape(-1)

        event = tick | start  # steps whose frame entered the history
        g = torch.cumsum(event.long(), 0) - 1  # index of the latest event at each step
        event_step = event.nonzero().squeeze(-1)  # step of each event
        seg = torch.cummax(torch.where(start, g, torch.full_like(g, -1)), 0).values

        last = event_step.numel() - 1

        def gather(shift: int) -> torch.Tensor:
            # shift=1: the history after pushing one more frame (its newest slot is overwritten)
            cols = [
                event_step[torch.maximum(g - o + shift, seg).clamp_max(last)] for o in self.offsets
            ]
            return frames[torch.stack(cols, -1)]  # [rows*T, n, H, W]

        stack = gather(0)
        tensordict.set(self.out_key, stack.reshape(*batch, self.num_frames, *hw))

        next_key = unravel_key(("next", self.in_key))
        if tensordict.get(next_key, None) is not None:
            next_frames = self._get_frame(tensordict, next_key).reshape(n_rows * t_len, *hw)
            next_tick_key = unravel_key(("next", self.tick_key)) if self.tick_key else None
            next_tick = batch_flag(tensordict, next_tick_key, batch, "tick")
            pushed = gather(1)
            pushed[:, -1] = next_frames  # the newest slot holds the next frame (offset 0)
            if next_tick is None:
                next_stack = pushed
            else:
                next_stack = torch.where(
                    expand_right(next_tick.reshape(-1), pushed), pushed, stack
                )
            tensordict.set(
                unravel_key(("next", self.out_key)),
                next_stack.reshape(*batch, self.num_frames, *hw),
            )
        return tensordict

    def __repr__(self) -> str:
        return (
            f"{type(self).__name__}(history={self.history}, stride={self.stride}, "
            f"in_key={self.in_key!r}, out_key={self.out_key!r}, tick_key={self.tick_key!r})"
        )
