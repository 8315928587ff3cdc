"""PerceptionHold: run perception at the perception rate, hold its outputs at the control rate.

Paper (TC-ViT, "4) Synchronize perception and control"): depth arrives at ~10 Hz, control
runs at 50 Hz. *Latent tiling*: z_uni is tiled five times per perception cycle.
*Nearest-goal forwarding*: only the immediate goal g_1 is passed to the locomotion module.

Why one file of ~600 lines: it is one module, :class:`PerceptionHold`, whose class docstring (the
timing and state contract, ~120 lines) and shape resolution share its held keys and buffers.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping, Sequence

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase, TensorDictSequential
from tensordict.utils import NestedKey, unravel_key, unravel_key_list
from torchrl.data import Binary, Composite, TensorSpec, Unbounded
from torchrl.envs import TensorDictPrimer
from torchrl.modules import set_recurrent_mode

from legoh_rl.transforms._common import batch_flag

__all__ = ["PerceptionHold"]

_DEFAULT_SHAPES = {"z_uni": (32,), "delta_g0": (2,), "goals_uni": (3, 2)}
_SRC_OUT_SHAPES = "out_shapes"
_SRC_SPEC = "the perception module's spec"
_SRC_DRY_RUN = "the dry run on example_input"
_SRC_DEFAULT = "LEGO-H's default shapes (docs/keys.md)"


def _held_key(key: NestedKey, prefix: str) -> NestedKey:
    key = unravel_key(key)
    if isinstance(key, str):
        return prefix + key
    return (*key[:-1], prefix + key[-1])


def _next(key: NestedKey) -> NestedKey:
    return unravel_key(("next", key))


class PerceptionHold(TensorDictModuleBase):
    """Wraps a perception module so it runs only on perception ticks, per world.

    **What it does (acting, batch ``[B]``).** For each world, the *effective tick* is::

        tick = tick_key | is_init | ~held_valid        (a missing tick_key counts as True)

    Worlds with ``tick`` True are gathered into a sub-batch and the perception module (e.g.
    TC-ViT, any ``TensorDictModuleBase`` writing ``hold_keys``) runs on that sub-batch only,
    so the cost is proportional to the number of ticking worlds. The other worlds get the
    values held since their last tick ("latent tiling"). Every world gets
    ``goal_next = goals_uni[..., goal_index, :]`` (row 0 = g_1, "nearest-goal forwarding").
    A resetting world (``is_init`` True, from torchrl's ``InitTracker``) or a world with no
    valid held value (``held_valid`` False, e.g. just primed) is always a tick, whatever the
    env's tick flag says: nothing computed before a reset may leak into the new episode.

    **Where the held values live: in the tensordict, not in this module.** The module writes
    ``("next", held_<k>)`` for every ``k`` in ``hold_keys`` and ``("next", "held_valid")``;
    :meth:`make_tensordict_primer` registers those keys in the env's state spec, so the env
    carries them from step to step and zeroes them (``held_valid`` False) on (partial)
    resets, exactly like torchrl's recurrent modules carry their hidden state. So the module
    is stateless: it works in a ``Collector``, in a ``ParallelEnv``, with any batch size,
    and every stored step carries the values the policy held, which makes training
    consistent with acting (:meth:`hold_forward`). ``Collector(auto_register_policy_transforms
    =True)`` and ``torchrl.modules.utils.get_primers_from_module`` find the primer. Without
    the primer the held keys are dropped between steps and every step is a tick (correct,
    no savings; a warning says so).

    **Recurrent perception.** If the perception module carries a recurrent state (a torchrl
    ``GRUModule``/``LSTMModule`` reading ``key`` and writing ``("next", key)``), the state must
    advance only on ticks. Those keys are found automatically (``recurrent_keys=None``: every
    ``key`` in the module's ``in_keys`` with ``("next", key)`` in its ``out_keys``); for
    non-ticking worlds ``("next", key)`` is set to the unchanged root ``key``. The module's own
    primer (``GRUModule.make_tensordict_primer()``) and ``InitTracker`` are still needed.

    **Training ([N, T] batches).** :meth:`hold_forward` recomputes the outputs with gradients
    on the tick steps only and broadcasts each to the following non-tick steps (index
    gather), reproducing what the policy held while acting.

    **Cheaper training passes: the encoder's features recorded while acting.** With
    ``feature_key`` (the output of the perception's first module, its encoder, e.g. TC-ViT's
    ``perception_features``), acting also writes that feature for every world (the fresh value
    on ticking worlds, zeros elsewhere; no gradient), so the collected batch holds what the
    encoder produced at each tick. :meth:`hold_forward` with ``encoder_grad_fraction=f < 1``
    then runs the encoder, with gradients, on a random fraction ``f`` of the tick steps only and
    takes the recorded features on the others, before the rest of the perception module (memory,
    heads) runs on every tick as usual. The encoder's forward and backward pass, most of a
    training pass for TC-ViT, then cost ``f`` of a full pass; the recorded features are those of
    the weights that acted (exact on the first pass over an on-policy batch, a few optimiser
    steps old on later passes), and the encoder's gradient is an estimate from the sampled ticks
    (``f`` times the full one in expectation; not rescaled).

    **Held shapes.** The primer and :meth:`output_spec` need the feature shape (no batch
    dims) of every ``hold_keys`` output. They are resolved per key, first match wins:

    1. ``out_shapes`` given explicitly;
    2. the perception module's output spec, ``perception.spec`` (torchrl's attribute for a
       module's output spec, as on ``SafeModule`` / ``ProbabilisticActor``): a
       ``Composite`` whose leaves' shapes, after the ``Composite``'s own batch shape, are the
       feature shapes. Every network of :func:`legoh_rl.modules.perception.make_perception`
       carries one built from its config (``latent_dim``, ``num_goals``), so
       ``PerceptionHold(make_tcvit(cfg))`` needs nothing else, whatever the sizes;
    3. a dry run: with ``example_input`` (a ``TensorDict`` or a ``Composite`` spec, e.g.
       ``env.fake_tensordict()`` or ``env.observation_spec``, holding the perception's inputs
       with any batch size), the module runs once at construction, without gradient, on
       a copy of those inputs (``spec.zero()`` for a spec; a missing ``is_init_key`` the
       module reads is set True, a first step), and the shapes it writes are used;
    4. otherwise LEGO-H's sizes: ``z_uni`` (32,), ``delta_g0`` (2,), ``goals_uni`` (3, 2).

    Sources that disagree (``out_shapes`` vs the spec or the dry run, the spec vs the dry
    run) raise ``ValueError`` naming the key and both shapes. Every perception forward
    is checked against the resolved shapes too, so a module writing another shape fails
    there with the same kind of message (not deep inside torchrl's stacking);
    ``shape_sources`` says where each shape came from.

    Keys (defaults from ``docs/keys.md``, all configurable):

    ============================  ==============  =====================================
    key                           shape           role
    ============================  ==============  =====================================
    perception ``in_keys``        module's        read on ticks (e.g. depth_goal_stack)
    ``perception_tick``           ``(1,)`` bool   env tick flag (optional)
    ``is_init``                   ``(1,)`` bool   InitTracker flag (optional)
    ``held_z_uni`` ...            as outputs      held values (primer)
    ``held_valid``                ``(1,)`` bool   held values exist (primer)
    ``z_uni``                     ``(L,)``        output (held between ticks), L = 32
    ``delta_g0``                  ``(2,)``        output (held between ticks)
    ``goals_uni``                 ``(N, 2)``      output (held between ticks), N = 3
    ``goal_next``                 ``(2,)``        ``goals_uni[..., 0, :]`` (g_1)
    ============================  ==============  =====================================

    Args:
        perception: the perception module (``TensorDictModuleBase``).
        tick_key: env perception-tick flag; ``None`` or absent = every step ticks.
        is_init_key: episode-start flag (``InitTracker``); ``None`` disables.
        hold_keys: perception outputs to hold. Default ``("z_uni", "delta_g0", "goals_uni")``.
        goals_key: the anticipated-goals output, ``(..., N, goal_dim)``; must be in
            ``hold_keys``. Default ``"goals_uni"``.
        goal_next_key: where g_1 is written. Default ``"goal_next"``.
        goal_index: which goal row is forwarded (0 = g_1).
        held_prefix: prefix of the held keys. Default ``"held_"``.
        valid_key: the held-valid flag key. Default ``"held_valid"``.
        recurrent_keys: recurrent state keys of ``perception``; ``None`` = detect.
        out_shapes: feature shape of each ``hold_keys`` entry, for the primer and
            :meth:`output_spec`; checked against the module's spec / the dry run. Default
            ``None``: inferred (see "Held shapes"); entries for keys not in ``hold_keys``
            are ignored.
        example_input: ``TensorDictBase`` or ``Composite`` to dry-run the module on when
            its shapes are not otherwise known (see "Held shapes"). ``None``: no dry run.
        feature_key: the only output of the perception's first module (its encoder) when the
            perception is a ``TensorDictSequential`` of two or more modules: acting records it
            (see "Cheaper training passes"). ``None`` (default): nothing recorded.

    Example:
        >>> hold = PerceptionHold(tcvit)                  # tcvit writes z_uni, delta_g0, goals_uni
        >>> hold.out_shapes, hold.shape_sources["z_uni"]  # from tcvit.spec (its config)
        ({'z_uni': (32,), 'delta_g0': (2,), 'goals_uni': (3, 2)}, "the perception module's spec")
        >>> policy = TensorDictSequential(hold, locomotion)  # locomotion reads z_uni, goal_next
        >>> env = TransformedEnv(env, Compose(InitTracker(), hold.make_tensordict_primer()))
        >>> rollout = env.rollout(100, policy)            # one TC-ViT forward per 5 steps/world
        >>> hold.hold_forward(batch)                      # training: [N, T] with gradients
    """

    def __init__(
        self,
        perception: TensorDictModuleBase,
        *,
        tick_key: NestedKey | None = "perception_tick",
        is_init_key: NestedKey | None = "is_init",
        hold_keys: Sequence[NestedKey] = ("z_uni", "delta_g0", "goals_uni"),
        goals_key: NestedKey = "goals_uni",
        goal_next_key: NestedKey = "goal_next",
        goal_index: int = 0,
        held_prefix: str = "held_",
        valid_key: NestedKey = "held_valid",
        recurrent_keys: Sequence[NestedKey] | None = None,
        out_shapes: Mapping[NestedKey, Sequence[int]] | None = None,
        example_input: TensorDictBase | Composite | None = None,
        feature_key: NestedKey | None = None,
    ) -> None:
        super().__init__()
        if not (hasattr(perception, "in_keys") and hasattr(perception, "out_keys")):
            raise TypeError(
                "PerceptionHold: perception must be a TensorDictModuleBase with in_keys and "
                f"out_keys, got {type(perception).__name__}"
            )
        if not held_prefix:
            raise ValueError("PerceptionHold: held_prefix must be a non-empty string")
        self.perception = perception
        self.hold_keys = unravel_key_list(list(hold_keys))
        if not self.hold_keys:
            raise ValueError("PerceptionHold: hold_keys must name at least one output")
        self.goals_key = unravel_key(goals_key)
        if self.goals_key not in self.hold_keys:
            raise ValueError(
                f"PerceptionHold: goals_key {goals_key!r} must be one of hold_keys {self.hold_keys}"
            )
        missing = [k for k in self.hold_keys if k not in unravel_key_list(perception.out_keys)]
        if missing:
            raise ValueError(
                f"PerceptionHold: hold_keys {missing} are not among the perception module's "
                f"out_keys {perception.out_keys}"
            )
        self.goal_index = int(goal_index)
        self.tick_key = None if tick_key is None else unravel_key(tick_key)
        self.is_init_key = None if is_init_key is None else unravel_key(is_init_key)
        self.goal_next_key = unravel_key(goal_next_key)
        self.valid_key = unravel_key(valid_key)
        self.held_keys = {k: _held_key(k, held_prefix) for k in self.hold_keys}
        p_in = unravel_key_list(list(perception.in_keys))
        p_out = unravel_key_list(list(perception.out_keys))
        if recurrent_keys is None:
            recurrent_keys = [k for k in p_in if _next(k) in p_out]
        self.recurrent_keys = unravel_key_list(list(recurrent_keys))
        self.feature_key = None if feature_key is None else unravel_key(feature_key)
        self._encoder = self._rest = None
        if self.feature_key is not None:
            self._encoder, self._rest = self._split_encoder(perception, self.feature_key)
        #: the recorded feature's shape (the encoder's ``out_dim``), ``None`` without ``feature_key``
        self.feature_shape = None if self._encoder is None else (int(self._encoder_dim(self._encoder)),)
        resolved = self._resolve_shapes(out_shapes, example_input)
        self.out_shapes = {k: shape for k, (shape, _) in resolved.items()}
        self.shape_sources = {k: src for k, (_, src) in resolved.items()}
        self._warned_no_state = False

        extra_in = [k for k in (self.tick_key, self.is_init_key) if k is not None]
        in_keys = p_in + extra_in + list(self.held_keys.values()) + [self.valid_key]
        self.in_keys = list(dict.fromkeys(in_keys))
        out_keys = (
            list(self.hold_keys)
            + [self.goal_next_key]
            + [_next(h) for h in self.held_keys.values()]
            + [_next(self.valid_key)]
            + [_next(r) for r in self.recurrent_keys]
            + ([] if self.feature_key is None else [self.feature_key])
        )
        self.out_keys = list(dict.fromkeys(out_keys))

    @staticmethod
    def _encoder_dim(encoder) -> int:
        dim = getattr(getattr(encoder, "module", encoder), "out_dim", None)
        if not isinstance(dim, int):
            raise ValueError(
                "PerceptionHold: feature_key needs the encoder (the perception's first module) to "
                f"declare its output width as an int attribute out_dim; {type(encoder).__name__} has {dim!r}"
            )
        return dim

    @staticmethod
    def _split_encoder(perception, feature_key) -> tuple[TensorDictModuleBase, TensorDictSequential]:
        """``(encoder, rest)`` of a perception whose first module writes ``feature_key`` alone."""
        modules = list(getattr(perception, "module", ())) if isinstance(perception, TensorDictSequential) else []
        if len(modules) < 2 or unravel_key_list(list(modules[0].out_keys)) != [feature_key]:
            first = unravel_key_list(list(modules[0].out_keys)) if modules else None
            raise ValueError(
                f"PerceptionHold: feature_key={feature_key!r} needs a TensorDictSequential perception of "
                f"two or more modules whose first writes only that key; got {type(perception).__name__} "
                f"with first out_keys {first}"
            )
        return modules[0], TensorDictSequential(*modules[1:])

    # ------------------------------------------------------------------ held shapes
    def _spec_shapes(self) -> dict:
        """Feature shapes of ``hold_keys`` declared by ``perception.spec`` (a Composite)."""
        try:
            spec = getattr(self.perception, "spec", None)
        except Exception:  # a module whose spec property raises: no spec
            spec = None
        if not isinstance(spec, Composite):
            return {}
        shapes = {}
        for k in self.hold_keys:
            try:
                leaf = spec[k]
            except KeyError:
                continue
            if leaf is None:
                continue
            shapes[k] = tuple(int(d) for d in leaf.shape[spec.ndim:])
        return shapes

    def _dry_run_shapes(self, example: TensorDictBase | Composite) -> dict:
        """Feature shapes of ``hold_keys`` written by one no-grad forward on ``example``."""
        if isinstance(example, TensorSpec):
            example = example.zero()
        if not isinstance(example, TensorDictBase):
            raise TypeError(
                "PerceptionHold: example_input must be a TensorDict or a Composite spec, got "
                f"{type(example).__name__}"
            )
        sub = example.select(*self.perception.in_keys, strict=False).clone()
        init = self.is_init_key
        if init is not None and init in unravel_key_list(list(self.perception.in_keys)):
            if sub.get(init, None) is None:  # a first step, as for a fresh env
                sub.set(init, torch.ones((*sub.batch_size, 1), dtype=torch.bool, device=sub.device))
        try:
            with torch.no_grad():
                out = self.perception(sub)
        except Exception as err:
            raise RuntimeError(
                "PerceptionHold: the dry run of the perception module on example_input failed "
                f"({type(err).__name__}: {err}); example_input must hold its in_keys "
                f"{self.perception.in_keys}, or pass out_shapes"
            ) from err
        out = sub if out is None else out
        shapes = {}
        for k in self.hold_keys:
            value = out.get(k, None)
            if value is None:
                raise KeyError(f"PerceptionHold: the dry run on example_input did not write {k!r}")
            shapes[k] = tuple(value.shape[sub.batch_dims:])
        return shapes

    def _resolve_shapes(self, out_shapes, example_input) -> dict:
        """``{key: (feature shape, source)}``: out_shapes > spec > dry run > defaults."""
        found: dict = {}

        def add(key, shape, source) -> None:
            if key in found and found[key][0] != shape:
                raise ValueError(
                    f"PerceptionHold: held shape of {key!r}: {source} gives {shape} but "
                    f"{found[key][1]} gives {found[key][0]}"
                )
            found.setdefault(key, (shape, source))

        if out_shapes is not None:
            for k, v in out_shapes.items():
                k = unravel_key(k)
                if k in self.hold_keys:
                    add(k, tuple(int(d) for d in v), _SRC_OUT_SHAPES)
        for k, shape in self._spec_shapes().items():
            add(k, shape, _SRC_SPEC)
        if example_input is not None:
            for k, shape in self._dry_run_shapes(example_input).items():
                add(k, shape, _SRC_DRY_RUN)
        for k in self.hold_keys:
            if k not in found and k in _DEFAULT_SHAPES:
                found[k] = (_DEFAULT_SHAPES[k], _SRC_DEFAULT)
        return {k: found[k] for k in self.hold_keys if k in found}

    def _check_output(self, out: TensorDictBase, batch_dims: int) -> None:
        """Raise if a perception output's feature shape is not the held shape."""
        for k in self.hold_keys:
            expected = self.out_shapes.get(k)
            got = tuple(out.get(k).shape[batch_dims:])
            if expected is not None and got != expected:
                raise ValueError(
                    f"PerceptionHold: the perception module wrote {k!r} with feature shape "
                    f"{got}, but the held shape is {expected} (from {self.shape_sources[k]}); "
                    f"pass out_shapes={{{k!r}: {got}}}, give the module a spec or an "
                    "example_input"
                )

    # ------------------------------------------------------------------ specs / primer
    def _shape(self, key: NestedKey) -> tuple[int, ...]:
        if key not in self.out_shapes:
            raise ValueError(
                f"PerceptionHold: no feature shape known for {key!r}; pass "
                f"out_shapes={{{key!r}: (...)}}"
            )
        return self.out_shapes[key]

    def output_spec(self, batch_size: Sequence[int] = ()) -> Composite:
        """Spec of what the module writes at the root: ``hold_keys`` and ``goal_next``."""
        batch = torch.Size(batch_size)
        specs = {k: Unbounded(shape=(*batch, *self._shape(k))) for k in self.hold_keys}
        goals_shape = self._shape(self.goals_key)
        if len(goals_shape) < 2:
            raise ValueError(
                f"PerceptionHold: {self.goals_key!r} must be (N, goal_dim), out_shapes says "
                f"{goals_shape}"
            )
        specs[self.goal_next_key] = Unbounded(shape=(*batch, *goals_shape[1:]))
        return Composite(specs, shape=batch)

    def held_spec(self, batch_size: Sequence[int] = ()) -> Composite:
        """Spec of the held state carried by the env: ``held_<k>`` and ``held_valid``."""
        batch = torch.Size(batch_size)
        specs = {h: Unbounded(shape=(*batch, *self._shape(k))) for k, h in self.held_keys.items()}
        specs[self.valid_key] = Binary(n=1, shape=(*batch, 1), dtype=torch.bool)
        return Composite(specs, shape=batch)

    def make_tensordict_primer(self) -> TensorDictPrimer:
        """A ``TensorDictPrimer`` adding the held state to the env (zeros / False on reset)."""
        return TensorDictPrimer(self.held_spec(), expand_specs=True)

    # ------------------------------------------------------------------ helpers
    def _run(self, td: TensorDictBase) -> TensorDictBase:
        sub = td.select(*self.perception.in_keys, strict=False)
        return self._checked(self.perception(sub), sub)

    def _checked(self, out: TensorDictBase | None, sub: TensorDictBase) -> TensorDictBase:
        """The perception's output (``sub`` when it wrote in place), checked to hold every held
        key at its shape and every recurrent key's next value."""
        out = sub if out is None else out
        for k in [*self.hold_keys, *(_next(r) for r in self.recurrent_keys)]:
            if out.get(k, None) is None:
                raise KeyError(f"PerceptionHold: the perception module did not write {k!r}")
        self._check_output(out, sub.batch_dims)
        return out

    def _run_cached(self, td: TensorDictBase, fraction: float, generator: torch.Generator | None = None) -> TensorDictBase:
        """:meth:`_run` with the encoder on a random ``fraction`` of ``td``'s samples (any batch
        shape) and the recorded ``feature_key`` on the others (detached)."""
        feats = td.get(self.feature_key).detach().clone()
        pick = torch.rand(td.batch_size, device=feats.device, generator=generator) < fraction
        if bool(pick.any()):
            sub = td.select(*self._encoder.in_keys, strict=False)[pick]
            feats = feats.to(torch.get_default_dtype())
            feats[pick] = self._encoder(sub).get(self.feature_key).to(feats.dtype)
        rest = td.select(*self._rest.in_keys, strict=False)
        rest.set(self.feature_key, feats)
        return self._checked(self._rest(rest), rest)

    def _has_state(self, td: TensorDictBase) -> bool:
        keys = [*self.held_keys.values(), self.valid_key]
        return all(td.get(k, None) is not None for k in keys)

    def _tick(self, td: TensorDictBase) -> tuple[torch.Tensor, bool]:
        """Effective tick (batch-shaped bool) and whether held state is present."""
        batch = td.batch_size
        device = td.device
        tick = batch_flag(td, self.tick_key, batch, "tick")
        if tick is None:
            tick = torch.ones(batch, dtype=torch.bool, device=device)
        init = batch_flag(td, self.is_init_key, batch, "is_init")
        if init is not None:
            tick = tick | init
        has_state = self._has_state(td)
        if has_state:
            tick = tick | ~batch_flag(td, self.valid_key, batch, "held_valid")
        return tick, has_state

    @staticmethod
    def _merge(held: torch.Tensor, mask: torch.Tensor, new: torch.Tensor, key) -> torch.Tensor:
        if held.shape[mask.ndim:] != new.shape[1:]:
            raise ValueError(
                f"PerceptionHold: held value {key!r} has feature shape "
                f"{tuple(held.shape[mask.ndim:])} but the perception module wrote "
                f"{tuple(new.shape[1:])}; fix out_shapes"
            )
        out = held.to(new.dtype).clone()
        out[mask] = new
        return out

    def _write(self, td, values, rec_next, batch) -> TensorDictBase:
        for k in self.hold_keys:
            td.set(k, values[k])
            td.set(_next(self.held_keys[k]), values[k])
        td.set(self.goal_next_key, values[self.goals_key][..., self.goal_index, :])
        td.set(_next(self.valid_key), torch.ones((*batch, 1), dtype=torch.bool, device=td.device))
        for r, v in rec_next.items():
            td.set(_next(r), v)
        return td

    # ------------------------------------------------------------------ acting
    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        """One control step: perception on ticking worlds only, held values elsewhere."""
        td = tensordict
        batch = td.batch_size
        tick, has_state = self._tick(td)
        if not has_state and not self._warned_no_state:
            flags = batch_flag(td, self.tick_key, batch, "tick")
            if flags is not None and not bool(flags.all()):
                warnings.warn(
                    "PerceptionHold: the held state keys "
                    f"{[*self.held_keys.values(), self.valid_key]} are missing, so perception "
                    "runs on every step; add PerceptionHold.make_tensordict_primer() to the env",
                    stacklevel=2,
                )
                self._warned_no_state = True
        if not has_state:
            tick = torch.ones_like(tick)
        out = None
        if bool(tick.all()):
            out = self._run(td)
            values = {k: out.get(k) for k in self.hold_keys}
            rec_next = {r: out.get(_next(r)) for r in self.recurrent_keys}
        elif not bool(tick.any()):
            values = {k: td.get(self.held_keys[k]) for k in self.hold_keys}
            rec_next = {r: td.get(r) for r in self.recurrent_keys}
        else:
            out = self._run(td.select(*self.perception.in_keys, strict=False)[tick])
            values = {
                k: self._merge(td.get(self.held_keys[k]), tick, out.get(k), k)
                for k in self.hold_keys
            }
            rec_next = {
                r: self._merge(td.get(r), tick, out.get(_next(r)), _next(r))
                for r in self.recurrent_keys
            }
        if self.feature_key is not None:
            self._record_features(td, tick, out)
        return self._write(td, values, rec_next, batch)

    def _record_features(self, td: TensorDictBase, tick: torch.Tensor, out: TensorDictBase | None) -> None:
        """Write ``feature_key`` for every world: the encoder's output on ticking worlds (``out``
        holds the ticking worlds, in order), zeros elsewhere; detached."""
        if out is not None and bool(tick.all()):
            td.set(self.feature_key, out.get(self.feature_key).detach())
            return
        feats = torch.zeros((*tick.shape, *self.feature_shape), device=td.device)
        if out is not None:
            fresh = out.get(self.feature_key).detach()
            feats = feats.to(fresh.dtype)
            feats[tick] = fresh
        td.set(self.feature_key, feats)

    # ------------------------------------------------------------------ training
    def hold_forward(self, tensordict: TensorDictBase, encoder_grad_fraction: float = 1.0,
                     generator: torch.Generator | None = None) -> TensorDictBase:
        """Training: recompute ``hold_keys`` on the tick steps of ``[..., T]`` data, hold between.

        ``tensordict`` has time as its last batch dim (a Collector batch ``[N, T]``, or a
        ``[T]`` trajectory). The effective tick of every step is computed as in
        :meth:`forward` (tick flag, ``is_init``, ``held_valid``). Each step ``t`` gets the
        outputs of the last tick step ``s <= t`` of its row: ``out[n, t] = f(x[n, s(n, t)])``,
        an index gather, so gradients flow to the tick steps. The perception module runs
        only on tick steps:

        * non-recurrent module: on the flat ``[M]`` batch of the M tick steps;
        * recurrent module (``recurrent_keys`` non-empty): on the tick steps of each row,
          compacted to ``[N, K]`` (K = most ticks in a row, shorter rows padded by repeating
          their last tick, whose outputs are discarded), under torchrl's
          ``set_recurrent_mode(True)``; the hidden state thus advances only on ticks, as
          while acting, from the stored state of the row's first tick.

        Steps before the first tick of a row (a slice starting between ticks) take the stored
        ``held_<k>`` values, exactly what the policy used; if those are not stored, the
        row's first step is treated as a tick. Writes ``hold_keys`` and ``goal_next`` for
        all ``[..., T]`` steps and returns ``tensordict``.

        ``encoder_grad_fraction`` ``f`` in ``(0, 1]``: below 1, with ``feature_key`` set and the
        recorded features in ``tensordict`` (and held state, so ticks are exactly those of
        acting), the encoder runs on a random fraction ``f`` of the tick steps (drawn from
        ``generator``, or torch's global generator when ``None``) and the recorded features stand
        in on the others (see "Cheaper training passes"); otherwise every tick step runs the
        whole module.
        """
        if not 0.0 < float(encoder_grad_fraction) <= 1.0:
            raise ValueError(f"PerceptionHold.hold_forward: encoder_grad_fraction must lie in (0, 1], "
                             f"got {encoder_grad_fraction!r}")
        td = tensordict
        if td.batch_dims == 0:
            raise ValueError(
                "PerceptionHold.hold_forward needs a time dimension (last batch dim), got "
                "batch_size=()"
            )
        batch = td.batch_size
        n_rows, t_len = batch[:-1].numel(), batch[-1]
        cached = (float(encoder_grad_fraction) < 1.0 and self.feature_key is not None
                  and td.get(self.feature_key, None) is not None)
        keys = [*self.in_keys, self.feature_key] if cached else self.in_keys
        tdf = td.select(*keys, strict=False).reshape(n_rows, t_len)
        tick, has_state = self._tick(tdf)
        cached = cached and has_state  # without held state the ticks may differ from acting's
        run = self._run if not cached else lambda x: self._run_cached(x, float(encoder_grad_fraction), generator)
        tick = tick.clone()  # may alias the stored flag
        if not has_state:
            tick[:, 0] = True
        device = tick.device
        steps = torch.arange(t_len, device=device).expand(n_rows, t_len)
        last = torch.cummax(torch.where(tick, steps, torch.full_like(steps, -1)), 1).values
        has_tick = last >= 0
        last = last.clamp_min(0)
        rows = torch.arange(n_rows, device=device).unsqueeze(-1)

        values: dict = {}
        if bool(tick.any()):
            sel = tdf.select(*self.perception.in_keys, *([self.feature_key] if cached else []), strict=False)
            if self.recurrent_keys:
                counts = tick.sum(1)
                k_max = int(counts.max())
                order = torch.argsort((~tick).to(torch.int8), dim=1, stable=True)[:, :k_max]
                kpos = torch.arange(k_max, device=device).expand(n_rows, k_max)
                fill = (counts - 1).clamp_min(0).unsqueeze(-1)
                comp = order.gather(1, torch.minimum(kpos, fill))  # [N, K] tick steps
                with set_recurrent_mode(True):
                    out = run(sel[rows, comp])
                rank = (torch.cumsum(tick.long(), 1) - 1).clamp_min(0)
                idx = rank.gather(1, last)  # [N, T] position in the compact row
                values = {k: out.get(k)[rows, idx] for k in self.hold_keys}
            else:
                out = run(sel[tick])
                rank = torch.cumsum(tick.reshape(-1).long(), 0) - 1
                flat_last = (rows * t_len + last).reshape(-1)
                idx = rank[flat_last].clamp_min(0).reshape(n_rows, t_len)
                values = {k: out.get(k)[idx] for k in self.hold_keys}
        if not bool(has_tick.all()):
            for k in self.hold_keys:
                stored = tdf.get(self.held_keys[k])
                if k not in values:
                    values[k] = stored.clone()
                else:
                    mask = has_tick.reshape(*has_tick.shape, *([1] * (stored.ndim - 2)))
                    values[k] = torch.where(mask, values[k], stored.to(values[k].dtype))
        for k in self.hold_keys:
            v = values[k]
            td.set(k, v.reshape(*batch, *v.shape[2:]))
        goals = td.get(self.goals_key)
        td.set(self.goal_next_key, goals[..., self.goal_index, :])
        return td
