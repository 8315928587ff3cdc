"""Train the LEGO-H oracle with PPO (paper "Oracle Policy Learning").

The oracle sees proprioception, scandots, privileged state and the expert navigation goals, and
learns the motor skills the student later distils. Every reward term and episode metric is
logged (wandb offline by default), the curriculum moves robots across trail levels, and
checkpoints are written atomically and can be resumed.

    python recipes/oracle_ppo.py                                  # CPU defaults
    python recipes/oracle_ppo.py env.robot=g1 env.num_envs=256
    python recipes/oracle_ppo.py checkpoint.resume=auto           # continue the last run
    python recipes/oracle_ppo.py checkpoint.init=checkpoints/oracle_h1.pt   # warm start from a policy
    python recipes/oracle_ppo.py env.foot_scan=true checkpoint.init=... checkpoint.init_widen=true
        # a warm start onto wider scandots: the new columns' first-layer weights start at zero
    python recipes/oracle_ppo.py device=cuda collector.workers=4  # a GPU for the networks, 4 collecting processes
    python recipes/oracle_ppo.py collector.workers=8 collector.backend=ray collector.ray.address=auto  # a Ray cluster
    python recipes/oracle_ppo.py kl_measure=loss_forward      # rsl_rl's KL order: ~20% less update time, other learning

The PPO update's cost and its switches (``kl_measure``, ``fused_adam``): BENCHMARKS.md, "The
oracle's update".
"""

from __future__ import annotations

import legoh_rl.openmp  # noqa: F401  (first: OpenMP's wait policy is read when torch loads)

# isort: split
import math
from pathlib import Path

import hydra
import torch
from omegaconf import DictConfig

from legoh_rl.envs.threads import torch_threads
from legoh_rl.modules.configs import OracleConfig
from legoh_rl.modules.distributions import set_action_std
from legoh_rl.modules.oracle import oracle_network_class, scandot_input_keys
from legoh_rl.objectives.ppo import (
    AdaptiveKLScheduler,
    make_ppo_loss,
    minibatch_keys,
    policy_kl,
    rollout_kl,
    set_loss_coefficients,
)
from legoh_rl.training import runner
from legoh_rl.training.builders import (
    check_recipe_settings,
    load_optimizer,
    make_adam,
    make_env,
    make_oracle,
    policy_meta,
    require_count,
    require_layers,
)
from legoh_rl.training.checkpoint import (
    check_meta,
    load_checkpoint,
    load_weights,
    require_training_state,
    resume_path,
    set_rng_state,
    widen_input_columns,
)
from legoh_rl.training.config_checks import Choice, Flag, Integer, ListOf, Name, Number, OneOf
from legoh_rl.training.config_store import env_config, ppo_config, register_configs
from legoh_rl.training.device import resolve_device
from legoh_rl.training.run_dir import check_run_dir
from legoh_rl.training.runner import Trainer
from legoh_rl.training.schedules import (
    INHERIT,
    RECORD_KEY,
    FeedforwardSchedule,
    check_anneal,
    inherited_schedule,
    recorded_schedule,
)
from legoh_rl.training.stages import run_experiment
from legoh_rl.training.stats import explained_variance

register_configs()  # the env and ppo groups' defaults, read from HikingEnvConfig and PPOConfig

#: the meta block's record of a run started from narrower scandots (``checkpoint.init_widen``:
#: :func:`init_networks`), kept by its checkpoints and exports
WIDENED_KEY = "init_widened"

#: ``kl_measure``'s choices: which KL to the rollout policy moves the learning rate (:func:`ppo_update`)
KL_MEASURES = ("after_step", "loss_forward")

#: this recipe's own settings by kind (beside builders' TRAINING_SETTINGS and the env and ppo
#: sections' dataclass fields);
#: model.layers has its own check (require_layers)
SETTINGS = {
    "model.init_std": Number(0, low_open=True),
    "model.max_std": Number(0, low_open=True, nullable=True),
    "model.start_std": Number(0, low_open=True, nullable=True),  # start_action_std
    "model.network": Name(),  # a name in ORACLE_NETWORKS: oracle_network_class
    "checkpoint.init": Name(nullable=True),
    "checkpoint.init_widen": Flag(),  # zero weights on the scandot columns checkpoint.init's networks lack
    "checkpoint.init_curriculum": Flag(),  # the worlds start on the levels checkpoint.init's curriculum left: init_curriculum
    # [start, end] (check_anneal), or inherit: feedforward_schedule
    "feedforward_anneal": OneOf((ListOf(Integer(0)), Choice((INHERIT,))), "[start_frames, end_frames] or inherit",
                                nullable=True),
    "update_threads": Integer(1, nullable=True),
    "kl_measure": Choice(KL_MEASURES),
}


def make_ppo(actor, critic, cfg: DictConfig, device: torch.device | str = "cpu", fused: bool = False):
    """Loss, GAE, optimiser and KL scheduler of the ``ppo`` section ``cfg`` (every
    :class:`~legoh_rl.objectives.ppo.PPOConfig` field); the loss's buffers (and GAE's) on
    ``device``, where ``actor`` and ``critic`` must already be (the optimiser holds their
    parameters); ``fused``: fused Adam (the ``fused_adam`` setting, :func:`make_adam`)."""
    ppo_cfg = ppo_config(cfg)
    loss, gae = make_ppo_loss(actor, critic, ppo_cfg)
    loss.to(device)
    optim = make_adam(loss.parameters(), ppo_cfg.learning_rate, fused)
    sched = AdaptiveKLScheduler(optim, ppo_cfg.desired_kl, min_lr=ppo_cfg.min_lr, max_lr=ppo_cfg.max_lr)
    return loss, gae, optim, sched


def validate(cfg: DictConfig) -> None:
    """Check every config value before any work (each error names the setting and its value)."""
    check_recipe_settings(cfg, Path(__file__).parent / "config" / "oracle_ppo.yaml", SETTINGS)
    env_config(cfg.env, "oracle")  # the env section's combinations (a gait clock for its terms, ...): nothing built
    ppo_config(cfg.ppo)  # the learning rate within the schedule's clamp
    require_count("collector", cfg.collector, "steps_per_env", "total_frames")
    require_count("checkpoint", cfg.checkpoint, "every")
    require_count("", cfg, "torch_threads")
    start, ceiling = cfg.model.get("start_std"), cfg.model.get("max_std")
    if start is not None and ceiling is not None and float(start) > float(ceiling):
        raise ValueError(f"model.start_std={start} is above model.max_std={ceiling}: the std would be capped at once")
    resolve_device(cfg.get("device"))
    runner.collector_workers(cfg)
    if cfg.get("update_threads") is not None:
        require_count("", cfg, "update_threads")
    require_layers("model.layers", cfg.model.get("layers"))
    try:
        oracle_network_class(str(cfg.model.network))
    except ValueError as err:
        raise ValueError(f"model.network={cfg.model.network!r}: {err}") from None
    resume_path(cfg.checkpoint.resume, cfg.checkpoint.dir)
    check_run_dir(cfg.checkpoint.dir, cfg.checkpoint.resume, bool(cfg.checkpoint.get("overwrite", False)))
    if cfg.checkpoint.get("init") is not None and not Path(cfg.checkpoint.init).is_file():
        raise FileNotFoundError(f"checkpoint.init: no policy at {cfg.checkpoint.init}")
    if cfg.get("feedforward_anneal") == INHERIT:
        schedule, _ = feedforward_schedule(cfg)  # refuses a checkpoint that records none, naming it
        if schedule.gain and not cfg.env.get("gait_period"):
            raise ValueError(f"feedforward_anneal=inherit: the inherited gain {schedule.gain} needs a gait clock, "
                             f"set env.gait_period > 0 (got {cfg.env.get('gait_period')!r})")
    elif check_anneal(cfg.get("feedforward_anneal")) is not None and not cfg.env.get("gait_feedforward"):
        raise ValueError("feedforward_anneal needs env.gait_feedforward > 0 (the gain it anneals from), "
                         f"got env.gait_feedforward={cfg.env.get('gait_feedforward')!r}")


def feedforward_schedule(cfg: DictConfig) -> tuple[FeedforwardSchedule | None, str]:
    """``(schedule, where it comes from)``: the gait feedforward gain this run follows over its own
    frames, ``None`` without ``feedforward_anneal`` (the env's gain stays).

    ``[start, end]``: ``env.gait_feedforward`` annealed over that window. ``inherit``: a resumed run
    goes on with the schedule its own checkpoint recorded; a fresh one with ``checkpoint.init``'s,
    moved on by the init's frame count (the gain it had at its last frame, the same slope), so that
    a stage started from another run's checkpoint continues its anneal with no copied numbers.

    Raises:
        ValueError: ``inherit`` without ``checkpoint.init`` on a fresh run, or from a checkpoint
            that records no schedule (the message names the file).
    """
    anneal = cfg.get("feedforward_anneal")
    if anneal is None:
        return None, "none"
    if anneal != INHERIT:
        return FeedforwardSchedule(float(cfg.env.gait_feedforward), check_anneal(anneal)), "env.gait_feedforward"
    resume = resume_path(cfg.checkpoint.resume, cfg.checkpoint.dir)
    if resume is not None:
        return recorded_schedule(load_checkpoint(resume), resume), f"the run's own {resume}"
    init = cfg.checkpoint.get("init")
    if init is None:
        raise ValueError("feedforward_anneal=inherit goes on with checkpoint.init's gait feedforward schedule: "
                         "set checkpoint.init (got null)")
    state = load_checkpoint(init)
    return inherited_schedule(state, init), f"checkpoint.init {init} at its {state['frames']} frames"


def set_feedforward(env, schedule: FeedforwardSchedule | None, frames: int) -> None:
    """The env's gait feedforward gain at ``frames`` run frames of ``schedule`` (None: no-op)."""
    if schedule is not None:
        env.set_gait_feedforward(schedule.at(frames))


def check_network(state: dict, networks, path: str, what: str) -> None:
    """Refuse a checkpoint of another oracle network than this run's ``model.network`` (a
    checkpoint that records none holds the default, ``mlp``)."""
    have = (state.get("oracle_config") or {}).get("network", OracleConfig.network)
    if have != networks.cfg.network:
        raise ValueError(f"{path} holds oracle network {have!r}: set model.network={have} to {what} "
                         f"(this run has model.network={networks.cfg.network})")


def init_networks(networks, env, path: str, widen: bool = False, state: dict | None = None) -> dict:
    """Start a fresh run from the networks of a policy file (slim export or training checkpoint).

    ``widen`` (``checkpoint.init_widen``): the file's networks read narrower scandots than this
    run's env gives (a policy trained before ``env.foot_scan`` or ``env.foot_scan_far``): the first layers that read the
    scandots (:func:`~legoh_rl.modules.oracle.scandot_input_keys`: the actor's and the critic's
    encoders) start with the file's weights on the old columns and zeros on the new ones
    (:func:`~legoh_rl.training.checkpoint.widen_input_columns`), every other weight is copied, so
    the run starts acting (and valuing) exactly as the file's policy did. ``state``: the file's
    contents when the caller has loaded them already (read from ``path`` otherwise).

    Returns:
        The run's meta record of the widening, ``{WIDENED_KEY: {"checkpoint": path, "scandots":
        [old, new] columns, "layers": {key: [old shape, new shape]}}}``; ``{}`` without one.

    Raises:
        ValueError: not an oracle policy; another network, robot, layout or gait clock; narrower
            scandots without ``widen`` (names the first layer, both its shapes and the switch);
            ``widen`` with scandots as wide as this run's (nothing to widen).
    """
    state = load_checkpoint(path) if state is None else state
    meta = state.get("meta", {})
    if "networks" not in state or meta.get("kind") != "oracle":
        raise ValueError(f"checkpoint.init: {path} holds no oracle networks (kind {meta.get('kind')!r})")
    check_network(state, networks, path, "start from it")
    weights, own, keys = state["networks"], networks.state_dict(), scandot_input_keys(networks)
    narrower = [k for k in keys if k in weights and tuple(weights[k].shape) != tuple(own[k].shape)]
    width = int(env.observation_spec["scandots"].shape[-1])
    if narrower and not widen:
        k = narrower[0]
        raise ValueError(f"checkpoint.init: {path}'s {k} is {tuple(weights[k].shape)}, this run's {tuple(own[k].shape)}: "
                         f"its networks read {weights[k].shape[-1]} scandot columns, this run's env gives {width} "
                         f"(env.foot_scan={env.cfg.foot_scan}, env.foot_scan_far={env.cfg.foot_scan_far}); "
                         "set checkpoint.init_widen=true to start from it with zero weights on the new columns")
    if widen and not narrower:
        raise ValueError(f"checkpoint.init_widen=true: {path}'s networks read this run's {width} scandot columns "
                         "already: nothing to widen (drop checkpoint.init_widen)")
    expected = policy_meta(env, "oracle")
    expected.pop("gait_feedforward", None)  # a warm start may go on with another gain (a later anneal stage)
    record = {}
    if widen:  # the widening accounts for the scandots' layout: all else must match
        weights, layers = widen_input_columns(weights, own, keys, path)
        expected["obs_layout"] = {**expected["obs_layout"], "scandots": meta.get("obs_layout", {}).get("scandots")}
        for key in ("foot_scan", "foot_scan_far"):  # the columns the widening adds may be either scan
            expected.pop(key, None)
            if key in meta:
                expected[key] = meta[key]
        old = int(state["networks"][narrower[0]].shape[-1])
        record = {WIDENED_KEY: {"checkpoint": str(path), "scandots": [old, width], "layers": layers}}
    check_meta(meta, expected, path)
    have = (state.get("oracle_config") or {}).get("actor_layers")
    load_weights(networks, weights, path, "networks",
                 f"checkpoint.init needs model.layers={list(have) if have else '<its sizes>'} (other network sizes "
                 f"than model.layers={list(networks.cfg.actor_layers)})")
    widened = (f"; scandot input layers {sorted(record[WIDENED_KEY]['layers'])} widened from "
               f"{record[WIDENED_KEY]['scandots'][0]} to {width} columns, the new ones zero" if record else "")
    print(f"initialised from {path} (its iteration {state.get('iteration')}, {state.get('frames')} frames){widened}")
    return record


def ppo_update(data, loss, gae, optim, sched, actor, cfg: DictConfig,
               generator: torch.Generator | None = None) -> dict[str, float]:
    """Epochs x mini-batches of clipped PPO on one collected ``[N, T]`` batch; returns mean diagnostics.

    GAE writes ``advantage``, ``value_target`` and ``state_value`` into ``data``; the minibatches
    are then indexed out of the entries the loss and the KL read only (:func:`minibatch_keys`):
    the same tensors as indexing the whole batch, without gathering the next observations, reward
    terms and counters 20 times an update (~9% of its time on 256 x 24 steps, BENCHMARKS.md).

    The KL to the rollout policy that moves the learning rate (:class:`AdaptiveKLScheduler`) is
    ``kl_measure``'s:

    * ``after_step`` (default): the stepped actor's on the minibatch it stepped on
      (:func:`policy_kl`: one more, gradient-free, actor pass a minibatch); it sets the next
      step's learning rate;
    * ``loss_forward``: rsl_rl's order: the loss's own forward pass (``policy_loc`` /
      ``policy_scale``, :func:`rollout_kl`: the parameters before this minibatch's step) sets
      this step's learning rate; no actor pass is added (~20% of the update). The batch's first
      minibatch leaves the rate as it is: no step has been taken on the batch yet, so its KL is
      the rollout policy's to itself (~0, which would raise the rate every update).

    ``train/kl`` is the mean of the KLs that moved the learning rate. ``generator``: what draws the
    minibatches (``None``: torch's global generator; ``collector.overlap`` gives the update its own,
    since the collecting thread draws the actions from the global one meanwhile).
    """
    kl_measure = cfg.get("kl_measure") or "after_step"
    if kl_measure not in KL_MEASURES:
        raise ValueError(f"kl_measure must be one of {list(KL_MEASURES)}, got {kl_measure!r}")
    with torch.no_grad():
        gae(data)
    flat = data.select(*minibatch_keys(loss, "loc", "scale"), strict=False).reshape(-1)
    sums: dict[str, float] = {}
    count = kl_count = 0
    kl_sum, lr = 0.0, sched.lr
    for _ in range(cfg.ppo.num_epochs):
        for idx in torch.randperm(flat.shape[0], generator=generator).chunk(cfg.ppo.num_minibatches):
            mb = flat[idx]
            out = loss(mb)
            if kl_measure == "loss_forward" and count > 0:  # the parameters after the previous step
                kl = rollout_kl(mb, out["policy_loc"], out["policy_scale"])
                lr, kl_sum, kl_count = sched.step(kl), kl_sum + float(kl), kl_count + 1
            total = out["loss_objective"] + out["loss_critic"] + out["loss_entropy"]
            optim.zero_grad()
            total.backward()
            grad_norm = torch.nn.utils.clip_grad_norm_(loss.parameters(), cfg.ppo.max_grad_norm)
            optim.step()
            if kl_measure == "after_step":
                kl = policy_kl(actor, mb)
                lr, kl_sum, kl_count = sched.step(kl), kl_sum + float(kl), kl_count + 1
            for key, value in (("loss/objective", out["loss_objective"]), ("loss/critic", out["loss_critic"]),
                               ("loss/entropy", out["loss_entropy"]), ("train/grad_norm", grad_norm),
                               ("train/clip_fraction", out.get("clip_fraction", torch.tensor(0.0)))):
                sums[key] = sums.get(key, 0.0) + float(value.detach() if torch.is_tensor(value) else value)
            count += 1
    stats = {k: v / count for k, v in sums.items()}
    stats["train/kl"] = kl_sum / kl_count if kl_count else math.nan  # loss_forward on one minibatch: none
    stats["train/lr"] = lr
    stats["train/explained_variance"] = explained_variance(data["state_value"], data["value_target"])
    stats["train/action_std"] = float(flat["scale"].mean())
    return stats


class OracleTrainer(Trainer):
    """Oracle PPO for the shared loop (:mod:`legoh_rl.training.runner`): the env is collected as
    it is, the actor samples, and each batch gets :func:`ppo_update`."""

    desc = "oracle PPO"
    collector_kwargs = {"auto_register_policy_transforms": False}  # the oracle is stateless
    overlap_ready = True  # with collector.overlap the update draws its minibatches from its own generator

    def __init__(self, cfg: DictConfig, env, networks, actor, loss, gae, optim, sched) -> None:
        self.cfg, self.env, self.collect_env, self.behaviour, self.device = cfg, env, env, actor, env.device
        self.networks, self.actor, self.loss, self.gae, self.optim, self.sched = networks, actor, loss, gae, optim, sched
        self.update_threads = int(cfg.torch_threads if cfg.get("update_threads") is None else cfg.update_threads)
        self.feedforward: FeedforwardSchedule | None = None  # None: the env's gain stays (build sets it)
        self.lineage: dict = {}  # the widening of checkpoint.init's networks, if any (build sets it)
        # collector.overlap: the minibatch draws' own generator (checkpointed as "minibatch_rng")
        self.generator = (torch.Generator().manual_seed(int(cfg.env.seed))
                          if cfg.collector.get("overlap", False) else None)

    @property
    def meta(self) -> dict:
        """What a loader must match, with the feedforward gain the last batch was collected with,
        and the record of a widened start (:data:`WIDENED_KEY`)."""
        return {**policy_meta(self.env, "oracle"), **self.lineage}

    def before_collect(self) -> None:
        set_feedforward(self.env, self.feedforward, self.frames)

    def collection_settings(self) -> dict[str, float]:
        return {"train/gait_feedforward": self.env.cfg.gait_feedforward}

    def sync_workers(self, workers, first: bool) -> None:
        """The feedforward gain of the next batch, in every worker's env."""
        workers.call("env.base_env.set_gait_feedforward", self.env.cfg.gait_feedforward)

    def update(self, data) -> dict[str, float]:
        with torch_threads(self.update_threads):  # the physics threads are idle during the update
            stats = ppo_update(data, self.loss, self.gae, self.optim, self.sched, self.actor, self.cfg,
                               self.generator)
        return stats

    def state_dict(self) -> dict:
        return {"loss": self.loss.state_dict(), "actor": self.actor.state_dict(),
                "networks": self.networks.state_dict(), "oracle_config": self.networks.cfg.__dict__,
                "optim": self.optim.state_dict(), "sched": self.sched.state_dict(),
                # what a resume or a later stage with feedforward_anneal=inherit goes on with
                RECORD_KEY: (self.feedforward or FeedforwardSchedule(self.env.cfg.gait_feedforward)).record(),
                **({} if self.generator is None else {"minibatch_rng": self.generator.get_state()})}

    def postfix(self, stats: dict) -> dict[str, str]:
        return {"reward": f"{stats['reward/total']:.3f}", "level": f"{stats['curriculum/mean_level']:.2f}",
                **super().postfix(stats)}


def build(cfg: DictConfig, env=None) -> OracleTrainer:
    """Env, networks, loss, optimiser and counters, restored from the checkpoint to resume."""
    validate(cfg)
    device = resolve_device(cfg.get("device"))
    torch.set_num_threads(int(cfg.torch_threads))
    torch.manual_seed(int(cfg.env.seed))
    env = env if env is not None else make_env(cfg.env, mode="oracle", device=str(device))
    if env.device != device:
        raise ValueError(f"the env given delivers its tensors on {env.device}, this run has device={device}")
    layers = tuple(cfg.model.layers) if cfg.model.get("layers") is not None else None
    max_std = cfg.model.get("max_std")
    networks, actor, critic = make_oracle(env, cfg.model.init_std, layers, None if max_std is None else float(max_std),
                                          network=str(cfg.model.network))
    networks.to(device)  # actor and critic are views of these modules
    loss, gae, optim, sched = make_ppo(actor, critic, cfg.ppo, device, fused=bool(cfg.get("fused_adam")))
    trainer = OracleTrainer(cfg, env, networks, actor, loss, gae, optim, sched)
    trainer.feedforward, source = feedforward_schedule(cfg)
    if trainer.feedforward is not None:
        print(f"gait feedforward: {trainer.feedforward.describe()} (from {source})")
    path = resume_path(cfg.checkpoint.resume, cfg.checkpoint.dir)
    if path is None:
        set_feedforward(env, trainer.feedforward, 0)
        if cfg.checkpoint.get("init") is not None:
            init = load_checkpoint(cfg.checkpoint.init)  # read once: networks, and the curriculum if asked
            trainer.lineage = init_networks(networks, env, cfg.checkpoint.init,
                                            widen=bool(cfg.checkpoint.get("init_widen", False)), state=init)
            start_action_std(cfg, actor, "checkpoint.init")
            if cfg.checkpoint.get("init_curriculum", False):
                init_curriculum(env, init, cfg.checkpoint.init)
    else:
        state = load_checkpoint(path)
        require_training_state(state, path, ("loss", "optim", "sched", "env", "rng", "frames"))
        set_feedforward(env, trainer.feedforward, state["frames"])
        expected = policy_meta(env, "oracle")
        if cfg.get("feedforward_anneal") is not None:  # saved one batch before the gain resumes at
            expected.pop("gait_feedforward", None)
        check_meta(state["meta"], expected, path)
        trainer.lineage = {k: state["meta"][k] for k in (WIDENED_KEY,) if k in state["meta"]}  # kept by every checkpoint
        check_network(state, networks, path, "resume it")
        have = (state.get("oracle_config") or {}).get("actor_layers")
        load_weights(loss, state["loss"], path, "networks",
                     f"set model.layers={list(have) if have else '<its sizes>'} to resume it (this run has "
                     f"model.layers={list(networks.cfg.actor_layers)})")
        set_loss_coefficients(loss, ppo_config(cfg.ppo))  # the config's weights, not the checkpoint's
        load_optimizer(optim, state["optim"])  # its moments, this run's fused_adam
        sched.load_state_dict(state["sched"])
        levels = env.curriculum.levels.copy()
        env.load_state_dict(state["env"])
        if not cfg.checkpoint.get("keep_curriculum", True):  # a new stage: worlds start again on env.levels
            env.curriculum.levels[:] = levels
        set_rng_state(state["rng"])
        if trainer.generator is not None and "minibatch_rng" in state:  # else: a run that did not overlap, seeded afresh
            trainer.generator.set_state(state["minibatch_rng"])
        trainer.iteration, trainer.frames, trainer.run_id = state["iteration"], state["frames"], state.get("run_id")
        print(f"resumed from {path}: iteration {state['iteration']}, {state['frames']} frames")
        if Path(path).resolve().parent != Path(cfg.checkpoint.dir).resolve():  # another run's state: a new stage
            start_action_std(cfg, actor, str(path))
    return trainer


#: the env fields that decide which world holds which category
#: (:func:`~legoh_rl.envs.curriculum.world_categories`), read by :func:`init_curriculum`
CURRICULUM_LAYOUT = ("num_envs", "categories", "category_weights")


def init_curriculum(env, state: dict, path: str) -> None:
    """``checkpoint.init_curriculum``: the worlds of a fresh run start on the levels the curriculum
    of ``state`` (the contents of ``path``, a training checkpoint ``last.pt``) left, as a stage resuming the previous one
    keeps them (``checkpoint.keep_curriculum``), where ``checkpoint.init`` carries the networks
    only (e.g. networks widened for more scandots, which a stage's resume cannot load).

    Raises:
        ValueError: ``path`` holds no env state (a slim export), or was trained with other worlds
            (one of :data:`CURRICULUM_LAYOUT` differs: names the field and both values).
    """
    if "env" not in state or "curriculum" not in state["env"]:
        raise ValueError(f"checkpoint.init_curriculum=true: {path} holds no curriculum state (a slim policy export?); "
                         "use a run's last.pt")
    theirs = (state.get("config") or {}).get("env") or {}
    for key in CURRICULUM_LAYOUT:
        mine = getattr(env.cfg, key)
        have = theirs.get(key)
        have = tuple(have) if isinstance(have, list | tuple) else have
        if have != mine:
            raise ValueError(f"checkpoint.init_curriculum=true: {path} was trained with env.{key}={have!r}, this run has "
                             f"{mine!r}: its worlds' levels would land on other worlds")
    env.curriculum.load_state_dict(state["env"]["curriculum"])
    print(f"curriculum levels from {path} (mean {env.curriculum.levels.mean():.2f}; checkpoint.init_curriculum)")


def start_action_std(cfg: DictConfig, actor: torch.nn.Module, source: str) -> float | None:
    """Set every action std of ``actor`` to ``model.start_std`` (when set) at the start of a run
    that begins from another run's networks (``checkpoint.init``, or a stage resuming the previous
    stage's ``last.pt``); a run resuming its own ``last.pt`` never calls this, so it resumes exactly.

    Why: the head's ``exp(log_std)`` is clamped at ``model.max_std``, and a clamp passes no gradient
    above its ceiling, so a ``log_std`` that once rose past it stays there: the std is then a
    constant, not learned. Set at or under the ceiling, it is learned again from there.

    Returns:
        the std set, or ``None`` (``model.start_std`` is null).
    """
    std = cfg.model.get("start_std")
    if std is None:
        return None
    set_action_std(actor, float(std))
    print(f"action std set to {float(std):g} on every action (model.start_std; the networks from {source})")
    return float(std)


def train(cfg: DictConfig, env=None) -> dict:
    """Run the oracle training described by ``cfg`` (:func:`legoh_rl.training.runner.train`);
    returns a summary of the last iteration (with ``interrupted``: the signal number, when
    SIGINT/SIGTERM stopped it after a checkpoint)."""
    return runner.train(cfg, validate, lambda c: build(c, env))


@hydra.main(config_path="config", config_name="oracle_ppo", version_base=None)
def main(cfg: DictConfig) -> None:
    runner.finish(run_experiment(cfg, train, "oracle_ppo"))


if __name__ == "__main__":
    main()
