"""Train the unified LEGO-H student: TC-ViT + locomotion module, distilled from a frozen oracle.

Paper "Unified Hiking Policy Learning with Vision" and "Hierarchical Latent Matching":

1. DAgger: the frozen oracle labels every step from the privileged state (``z_tea``, expert
   goals, its action) and the student minimises L_im (Eq. 1). The student acts, except that at
   each step the teacher's action is executed instead with probability beta (``dagger_beta0``,
   decayed linearly to 0 over the DAgger iterations, as in Ross et al.'s DAgger).
2. Then PPO (rewards, with point-navigation distance) + L_im + L_hie (Eqs. 6-9), while the masked
   VAE keeps training on the teacher's actions (L_rec, Eqs. 2-5) with its own optimiser.

The student perceives at 10 Hz and acts at 50 Hz (PerceptionHold); training recomputes perception
on the tick steps of each collected sequence so gradients reach TC-ViT exactly as it acted.

    python recipes/unified.py teacher=outputs/oracle_h1/last.pt
    python recipes/unified.py teacher=... hlm.enabled=false          # ablation "w TC-ViT"
    python recipes/unified.py teacher=... student.perception=eph     # baseline EP-H
    python recipes/unified.py experiment=... checkpoint.branch=runs/x/last.pt env.seed=1 hlm.enabled=false
        # a new run from another's state (weights, optimisers, curriculum, replay window, counters)
        # with its own random streams: ablations and seeds that share a first stage
    python recipes/unified.py experiment=... checkpoint.init=checkpoints/student_g1.pt
        # a fresh run from a student policy's perception and locomotion weights (a student
        # distilled again from a new teacher); everything else starts fresh
    python recipes/unified.py teacher=... device=cuda collector.workers=2   # GPU networks, 2 collecting processes
"""

from __future__ import annotations

import legoh_rl.openmp  # noqa: F401  (first: OpenMP's wait policy is read when torch loads)

# isort: split
import dataclasses
import functools
from pathlib import Path

import hydra
import torch
from omegaconf import DictConfig

from legoh_rl.modules.configs import PERCEPTION_PRESETS, LocomotionConfig
from legoh_rl.modules.distributions import set_action_std
from legoh_rl.modules.locomotion import locomotion_network_class
from legoh_rl.modules.masked_vae import MaskedVAEConfig
from legoh_rl.modules.perception import PERCEPTION_BUILDERS
from legoh_rl.objectives import DAggerLoss, HLMLoss, MaskedVAELoss
from legoh_rl.objectives.ppo import AdaptiveKLScheduler, make_ppo_loss, policy_kl
from legoh_rl.training import runner
from legoh_rl.training.builders import (
    check_recipe_settings,
    load_optimizer,
    make_adam,
    make_env,
    policy_env_kwargs,
    policy_meta,
    require_count,
)
from legoh_rl.training.checkpoint import (
    RENAMED,
    CheckpointError,
    check_meta,
    file_digest,
    load_checkpoint,
    load_weights,
    recorded_checkpoint,
    require_training_state,
    resume_path,
    set_rng_state,
)
from legoh_rl.training.config_checks import Choice, Flag, Integer, Name, Number
from legoh_rl.training.config_store import ppo_config, register_configs
from legoh_rl.training.device import resolve_device
from legoh_rl.training.distill import (
    STUDENT_ACTION_KEY,
    DAggerMixture,
    Teacher,
    dagger_beta,
    student_pass,
)
from legoh_rl.training.locomotion_replay import LocomotionReplay
from legoh_rl.training.run_dir import check_run_dir
from legoh_rl.training.runner import Trainer
from legoh_rl.training.stages import run_experiment
from legoh_rl.training.stats import explained_variance
from legoh_rl.training.student import LOCOMOTIONS, locomotion_network, make_student, student_env
from legoh_rl.training.weight_average import PolicyAverage

register_configs()  # the env and ppo groups' defaults, read from HikingEnvConfig and PPOConfig

#: this recipe's own settings by kind (beside builders' TRAINING_SETTINGS and the env and ppo
#: sections' dataclass fields; ``ppo.weight`` is this recipe's own key of the ppo section);
#: encoder_grad_fraction, dagger_minibatches and minibatch_split have their own checks in validate
SETTINGS = {
    "teacher": Name(),
    # the registry is the one list of networks, read when checked: a network registered by a
    # caller (PERCEPTION_BUILDERS.register(name, builder)) is a valid student.perception too
    "student.perception": Choice(lambda: sorted(PERCEPTION_BUILDERS)),
    "student.preset": Choice(tuple(PERCEPTION_PRESETS)),
    "student.init_std": Number(0, low_open=True, nullable=True),
    "student.ppo_join_std": Number(0, low_open=True, nullable=True),
    "student.locomotion": Choice(LOCOMOTIONS),
    "student.network": Name(),  # a name in LOCOMOTION_NETWORKS: check_locomotion
    "dagger_iters": Integer(0),
    "dagger_beta0": Number(0, 1),
    "dagger_decay_iters": Integer(1, nullable=True),
    "dagger_epochs": Integer(1),
    "dagger_replay.capacity": Integer(0, text=">= 0 (0: off)"),
    "dagger_replay.batch_size": Integer(1),
    "dagger_replay.steps": Integer(1),
    "ppo.weight": Number(0),
    **{f"imitation.{w}": Number(0) for w in ("w1", "w2", "w3", "w_priv")},
    "hlm.enabled": Flag(),
    "hlm.vanilla_vae": Flag(),
    **{f"hlm.{w}": Number(0) for w in ("w4", "w5", "w6", "w7", "w8", "c_mt", "c_ms")},
    "hlm.mask_ratio": Number(0, 1, high_open=True),
    "hlm.vae_lr": Number(0, low_open=True),
    "hlm.vae_steps": Integer(1),
    "hlm.warmup_iters": Integer(0),
    "checkpoint.branch": Name(nullable=True),
    "checkpoint.init": Name(nullable=True),
    "checkpoint.ema_decay": Number(0, 1, low_open=True, high_open=True, nullable=True),
    "allow_new_teacher": Flag(),
}
#: the ppo section's keys that are this recipe's, not PPOConfig fields
PPO_OWN = tuple(k.split(".", 1)[1] for k in SETTINGS if k.startswith("ppo."))


def validate(cfg: DictConfig) -> None:
    """Check every config value before any work (each error names the setting and its value);
    the env section's combinations are checked with the teacher's gait clock, by ``make_env``."""
    if cfg.get("teacher") is None:
        raise ValueError("teacher is required: the oracle checkpoint to distil (recipes/oracle_ppo.py)")
    check_recipe_settings(cfg, Path(__file__).parent / "config" / "unified.yaml", SETTINGS)
    check_locomotion(cfg)
    if not Path(cfg.teacher).is_file():
        renamed = RENAMED.get(str(cfg.teacher))
        raise FileNotFoundError(f"teacher: no checkpoint at {cfg.teacher}"
                                + (f" (renamed: teacher={renamed[0]})" if renamed else ""))
    ppo_config(cfg.ppo, PPO_OWN)  # the learning rate within the schedule's clamp
    require_count("collector", cfg.collector, "steps_per_env", "total_frames")
    require_count("checkpoint", cfg.checkpoint, "every")
    require_count("", cfg, "dagger_epochs", "torch_threads")
    fraction = cfg.get("encoder_grad_fraction", 1.0)
    if isinstance(fraction, bool) or not isinstance(fraction, (int, float)) or not 0 < fraction <= 1:
        raise ValueError(f"encoder_grad_fraction must be a number in (0, 1], got {fraction!r}")
    resolve_device(cfg.get("device"))
    runner.collector_workers(cfg)
    decay = cfg.get("dagger_decay_iters")
    if decay is not None and not 0 < decay <= cfg.dagger_iters:
        raise ValueError(f"dagger_decay_iters must lie in (0, dagger_iters={cfg.dagger_iters}], got {decay!r}")
    capacity = (cfg.get("dagger_replay") or {}).get("capacity", 0)
    if not int(capacity) >= 0:
        raise ValueError(f"dagger_replay.capacity must be >= 0 (0: off), got {capacity!r}")
    resume_path(cfg.checkpoint.resume, cfg.checkpoint.dir)
    branch = cfg.checkpoint.get("branch")
    if branch is not None and not Path(branch).is_file():
        raise FileNotFoundError(f"checkpoint.branch: no checkpoint at {branch}")
    init = cfg.checkpoint.get("init")
    if init is not None and not Path(init).is_file():
        raise FileNotFoundError(f"checkpoint.init: no student policy at {init}")
    if init is not None and branch is not None:
        raise ValueError(f"checkpoint.init ({init}) and checkpoint.branch ({branch}) both start a run from another "
                         "one: a branch carries a run's whole state, init a policy's weights only; set one")
    check_run_dir(cfg.checkpoint.dir, cfg.checkpoint.resume, bool(cfg.checkpoint.get("overwrite", False)))
    if cfg.get("minibatch_split", "permute") not in ("permute", "strided"):
        raise ValueError(f"minibatch_split must be permute or strided, got {cfg.get('minibatch_split')!r}")
    dagger_mb = cfg.get("dagger_minibatches")
    if dagger_mb is not None and (isinstance(dagger_mb, bool) or not isinstance(dagger_mb, int) or
                                  not 1 <= dagger_mb <= cfg.env.num_envs):
        raise ValueError(f"dagger_minibatches must be null (ppo.num_minibatches) or an integer in [1, env.num_envs="
                         f"{cfg.env.num_envs}], got {dagger_mb!r}")
    if cfg.ppo.num_minibatches > cfg.env.num_envs:
        raise ValueError(f"ppo.num_minibatches ({cfg.ppo.num_minibatches}) cannot exceed env.num_envs "
                         f"({cfg.env.num_envs}): minibatches split the worlds")


def frozen_oracle(cfg: DictConfig) -> bool:
    """Whether the student's locomotion is the teacher's actor, frozen (``student.locomotion=oracle``)."""
    return cfg.student.get("locomotion", "learned") == "oracle"


def check_locomotion(cfg: DictConfig) -> None:
    """``student.locomotion``: ``learned`` (the student's own network, ``student.network``) or
    ``oracle`` (RMA: the teacher's actor, frozen, fed by an adapter that estimates its latents).

    Raises:
        ValueError: an unknown value; a ``student.network`` that is not registered (the
            message lists the registered ones), or other than ``mlp`` with ``oracle`` (the
            teacher's network is used); ``oracle`` with a perception that does not estimate the
            privileged latent, with the DAgger replay window (it trains the locomotion module
            alone) or with HLM (a prior on the locomotion module's actions): each names the
            setting to change.
    """
    locomotion = cfg.student.get("locomotion", "learned")
    if locomotion not in LOCOMOTIONS:
        raise ValueError(f"unknown student.locomotion {locomotion!r}; valid: {list(LOCOMOTIONS)}")
    network = str(cfg.student.network)
    try:
        locomotion_network_class(network)
    except ValueError as err:
        raise ValueError(f"student.network={network!r}: {err}") from None
    if not frozen_oracle(cfg):
        return
    if network != LocomotionConfig.network:
        raise ValueError(f"student.network={network} names the student's own locomotion network, which "
                         "student.locomotion=oracle replaces by the teacher's actor: drop student.network")
    if cfg.student.perception not in ("rmah", "rmab"):
        raise ValueError(f"student.locomotion=oracle feeds the teacher's frozen actor with the perception's "
                         f"estimate of its privileged latent, which only rmah and rmab make; got "
                         f"student.perception={cfg.student.perception}")
    if int((cfg.get("dagger_replay") or {}).get("capacity", 0)) > 0:
        raise ValueError("student.locomotion=oracle freezes the locomotion module, which the DAgger replay "
                         "window trains: set dagger_replay.capacity=0")
    if cfg.hlm.enabled:
        raise ValueError("student.locomotion=oracle freezes the locomotion module, whose actions HLM shapes: "
                         "set hlm.enabled=false")


def check_network(meta: dict, run_meta: dict, path) -> None:
    """Refuse a checkpoint of another learned locomotion network than this run's
    ``student.network`` (a checkpoint that names none holds ``mlp``), before any weight is loaded.

    Raises:
        CheckpointError: names both networks and the setting.
    """
    if "locomotion_network" not in run_meta:  # a frozen oracle locomotion: the teacher's network
        return
    have, want = locomotion_network(meta), run_meta["locomotion_network"]
    if have != want:
        raise CheckpointError(f"{path} holds locomotion network {have!r}, this run has student.network={want}: "
                              f"set student.network={have} to continue it")


def check_teacher(state: dict, cfg: DictConfig, digest: str, path) -> None:
    """Refuse to resume a student with another teacher than it was distilled from, unless
    ``allow_new_teacher`` (a new stage under a new teacher, on purpose).

    Raises:
        CheckpointError: names both teachers and the switch.
    """
    if cfg.get("allow_new_teacher", False):
        return
    recorded = state.get("teacher", "")
    meant = recorded_checkpoint(recorded, state.get("teacher_sha256"))  # the file today, renames followed
    same = (state["teacher_sha256"] == digest if "teacher_sha256" in state  # older checkpoints: the path
            else Path(meant).resolve() == Path(cfg.teacher).resolve())
    if not same:
        was = recorded if meant == recorded else f"{recorded} (now {meant})"
        raise CheckpointError(f"{path} was distilled from teacher {was!r}, this run names "
                              f"{cfg.teacher!r} (other weights): pass teacher={meant} to continue, "
                              "or allow_new_teacher=true to go on under the new teacher")


def make_losses(student, critic, num_actions: int, cfg: DictConfig, device: torch.device | str = "cpu"):
    """PPO (with GAE), DAgger, masked-VAE and HLM losses, their parameters and buffers on ``device``
    (where ``student`` and ``critic`` must already be)."""
    ppo, gae = make_ppo_loss(student.actor, critic, ppo_config(cfg.ppo, PPO_OWN))
    # the privileged-latent term trains what a frozen oracle actor (student.locomotion=oracle) reads
    dagger = DAggerLoss(w1=cfg.imitation.w1, w2=cfg.imitation.w2, w3=cfg.imitation.w3,
                        w_priv=float(cfg.imitation.get("w_priv", 1.0)) if frozen_oracle(cfg) else 0.0)
    dagger.set_keys(action_uni=STUDENT_ACTION_KEY)
    h = cfg.hlm
    mask_ratio = 0.0 if h.vanilla_vae else h.mask_ratio
    vae = MaskedVAELoss(MaskedVAEConfig(action_dim=num_actions), w4=h.w4, w5=h.w5,
                        w6=0.0 if h.vanilla_vae else h.w6, mask_ratio=mask_ratio, seed=int(cfg.env.seed))
    hlm = HLMLoss(vae, w7=h.w7, w8=0.0 if h.vanilla_vae else h.w8, c_mt=h.c_mt, c_ms=h.c_ms,
                  mask_ratio=mask_ratio, seed=int(cfg.env.seed) + 1)
    hlm.set_keys(action_uni=STUDENT_ACTION_KEY)
    for module in (ppo, dagger, vae, hlm):
        module.to(device)
    return ppo, gae, dagger, vae, hlm


class UnifiedTrainer(Trainer):
    """The unified student for the shared loop (:mod:`legoh_rl.training.runner`): the student env
    (``collect_env``: depth history, goal tiling, perception hold on ``env``) is collected with
    the DAgger mixture of student and teacher, and each batch gets :func:`update`."""

    #: collector.overlap: the update draws from its own generator (:attr:`generator`) and the
    #: collecting copy of the DAgger mixture gets the schedule with the weights
    overlap_ready = True

    def __init__(self, cfg: DictConfig, **parts) -> None:
        self.cfg = cfg
        for name, value in parts.items():
            setattr(self, name, value)
        self.desc = f"unified ({cfg.student.perception})"
        self.behaviour = DAggerMixture(self.student.policy, self.teacher, seed=int(cfg.env.seed))
        self.env_wrap = functools.partial(student_env, student=self.student)  # each worker's transforms
        # collector.overlap: the update's minibatch and encoder-tick draws (checkpointed as "minibatch_rng")
        self.generator = (torch.Generator().manual_seed(int(cfg.env.seed) + 3)
                          if cfg.collector.get("overlap", False) else None)

    def before_collect(self) -> None:
        self.behaviour.beta = beta_at(self.iteration, self.cfg)
        self.behaviour.student_mean = self.iteration < self.cfg.dagger_iters

    def collection_settings(self) -> dict[str, float]:
        return {"train/dagger_beta": self.behaviour.beta}

    def refresh_overlap_policy(self, policy) -> None:
        """The student's weights (the teacher's are fixed) and the schedule :meth:`before_collect` set."""
        super().refresh_overlap_policy(policy)
        policy.set_schedule(self.behaviour.beta, self.behaviour.student_mean)

    def sync_workers(self, workers, first: bool) -> None:
        """The DAgger mixture's beta and mean switch in every worker's policy; first, a coin-flip
        stream of its own for each (``env.seed + 1000 k``)."""
        if first:
            seed = int(self.cfg.env.seed)
            workers.collector.map_fn("policy.reseed", [(seed + 1000 * k,) for k in range(workers.workers)])
        workers.call("policy.set_schedule", self.behaviour.beta, self.behaviour.student_mean)

    def update(self, data) -> dict[str, float]:
        stats = update(self, data, self.iteration, self.cfg)
        stats["train/teacher_acted"] = float(data["teacher_acted"].float().mean())
        return stats

    def state_dict(self) -> dict:
        return {"perception": self.student.perception.state_dict(), "actor": self.student.actor.state_dict(),
                "critic": self.critic_nets.state_dict(), "vae": self.vae.state_dict(), "optim": self.optim.state_dict(),
                "sched": self.sched.state_dict(), "vae_optim": self.vae_optim.state_dict(),
                "teacher": str(self.cfg.teacher), "teacher_sha256": self.teacher_sha256,
                "replay": None if self.replay is None else self.replay.state_dict(),
                "weight_average": None if self.average is None else self.average.state_dict(),
                **({} if self.generator is None else {"minibatch_rng": self.generator.get_state()})}

    def postfix(self, stats: dict) -> dict[str, str]:
        return {"im": f"{stats.get('loss/im_action', float('nan')):.3f}", **super().postfix(stats)}


def build(cfg: DictConfig) -> UnifiedTrainer:
    """Teacher, env, student, critic, losses, optimisers and counters (restored on resume)."""
    validate(cfg)
    device = resolve_device(cfg.get("device"))
    torch.set_num_threads(int(cfg.torch_threads))
    torch.manual_seed(int(cfg.env.seed))
    teacher = Teacher(cfg.teacher, cfg.env.robot, device)
    base = make_env(cfg.env, mode="student", device=str(device), **policy_env_kwargs(teacher.meta))  # the teacher's clock, scandots
    init_std = cfg.student.get("init_std") or float(teacher.action_std.mean())  # null: the teacher's
    oracle = frozen_oracle(cfg)
    oracle_config = dataclasses.asdict(teacher.networks.cfg) if oracle else None
    student = make_student(base, cfg.student.perception, cfg.student.preset, init_std=float(init_std),
                           oracle_config=oracle_config, record_features=grad_fraction(cfg) < 1,
                           network=str(cfg.student.network))
    if oracle:  # RMA: the teacher's actor, frozen, is the student's locomotion
        student.actor.module[0].module.load_state_dict(teacher.networks.actor.state_dict())
    student.policy.to(device)  # perception (in its hold) and locomotion
    env = student_env(base, student)
    critic, critic_nets = teacher.make_critic()
    ppo, gae, dagger, vae, hlm = make_losses(student, critic, base.A, cfg, device)
    params = [q for q in (*student.perception.parameters(), *student.actor.parameters(), *critic.parameters())
              if q.requires_grad]  # not a frozen oracle locomotion
    ppo_cfg = ppo_config(cfg.ppo, PPO_OWN)
    optim = make_adam(params, ppo_cfg.learning_rate, bool(cfg.get("fused_adam")))  # fused: one kernel a step
    sched = AdaptiveKLScheduler(optim, ppo_cfg.desired_kl, min_lr=ppo_cfg.min_lr, max_lr=ppo_cfg.max_lr)
    vae_optim = torch.optim.Adam(vae.parameters(), lr=cfg.hlm.vae_lr)
    meta = {**policy_meta(base, "student"), "perception": cfg.student.perception, "preset": cfg.student.preset}
    if oracle:  # learned locomotion: no entries, as in every checkpoint made before the option
        meta.update(locomotion="oracle", oracle_config=oracle_config)
    else:  # the network's name, by which evaluation and export rebuild it
        meta["locomotion_network"] = str(cfg.student.network)
    rp = cfg.get("dagger_replay") or {}
    replay = None
    if int(rp.get("capacity", 0)) > 0:  # aggregated DAgger data for the locomotion module
        replay = LocomotionReplay(student.actor, int(rp.capacity), int(rp.batch_size), int(rp.steps),
                                  seed=int(cfg.env.seed) + 2, device=device)
    p = UnifiedTrainer(cfg, replay=replay, teacher=teacher, env=base, collect_env=env, student=student, critic=critic,
                       critic_nets=critic_nets, ppo=ppo, gae=gae, dagger=dagger, vae=vae, hlm=hlm, optim=optim,
                       sched=sched, vae_optim=vae_optim, meta=meta, teacher_sha256=file_digest(cfg.teacher),
                       device=device)
    decay = cfg.checkpoint.get("ema_decay")
    if decay is not None:  # snapshots of the weights' moving average beside the raw ones (training unchanged)
        p.average = PolicyAverage({"perception": student.perception, "actor": student.actor}, float(decay))
    path = resume_path(cfg.checkpoint.resume, cfg.checkpoint.dir)
    branch = cfg.checkpoint.get("branch")
    if path is not None:
        state = load_checkpoint(path)
        restore(p, state, path, exact=True)
        if "branched_from" in state["meta"]:
            p.meta["branched_from"] = state["meta"]["branched_from"]
        print(f"resumed from {path}: iteration {state['iteration']}, {state['frames']} frames")
    elif branch is not None:
        state = load_checkpoint(branch)
        restore(p, state, branch, exact=False)
        p.meta["branched_from"] = {"checkpoint": str(branch), "sha256": file_digest(branch),
                                   "iteration": int(state["iteration"]), "frames": int(state["frames"]),
                                   "experiment": state["meta"].get("experiment")}
        print(f"branched from {branch}: iteration {state['iteration']}, {state['frames']} frames; "
              f"random streams from env.seed={cfg.env.seed}")
    elif cfg.checkpoint.get("init") is not None:
        p.meta[INIT_KEY] = init_student(p, cfg.checkpoint.init)
        print(f"perception and locomotion weights from {cfg.checkpoint.init}; the rest starts fresh")
    if path is not None and INIT_KEY in state["meta"]:  # kept by every checkpoint and export of the run
        p.meta[INIT_KEY] = state["meta"][INIT_KEY]
    join_std = cfg.student.get("ppo_join_std")
    if join_std is not None and path is None and p.iteration == cfg.dagger_iters:
        # a run (or branch) that starts where PPO joins: no DAgger update of its own will set it
        set_action_std(student.actor, float(join_std))
    return p


#: the meta block's record of a run started from a student policy's weights (``checkpoint.init``)
INIT_KEY = "initialised_from"
#: what a student policy must share with this run to start it: the robot, what it observes and acts
#: on, the gait clock its proprioception carries, and its perception (the teacher may differ)
INIT_META = ("robot", "num_actions", "obs_layout", "gait_period", "gait_stance", "perception", "preset")
#: observations only the teacher reads: their width follows the teacher's foot scan (``foot_scan``,
#: ``foot_scan_far``), so a student may start a run whose teacher sees more terrain than its own did
TEACHER_ONLY_OBS = ("scandots",)


def _student_fields(meta: dict) -> dict:
    """``meta``'s :data:`INIT_META` fields, its ``obs_layout`` without :data:`TEACHER_ONLY_OBS`."""
    out = {k: meta.get(k) for k in INIT_META}
    if isinstance(out["obs_layout"], dict):
        out["obs_layout"] = {k: v for k, v in out["obs_layout"].items() if k not in TEACHER_ONLY_OBS}
    return out


def init_student(p: UnifiedTrainer, path: str) -> dict:
    """``checkpoint.init``: a fresh run's perception and locomotion module start from a student
    policy's weights (a slim export of ``recipes/export_policy.py`` or a run's ``last.pt``), as when
    a student is distilled again from a new teacher; the critic, the masked VAE, the optimisers, the
    curriculum, the DAgger replay window, the counters and the weight average start fresh.

    Returns:
        the run's meta record: ``{"checkpoint": path, "sha256", "experiment", "frames",
        "teacher_sha256"}`` (the policy's own teacher, which may differ from this run's).

    Raises:
        ValueError: not a student policy; another robot, observation layout (the teacher's
            scandots aside), gait clock, perception or preset (names each field with both values);
            another locomotion network.
        CheckpointError: weights of other shapes (names the setting to fix).
    """
    state = load_checkpoint(path)
    meta = state.get("meta", {})
    if meta.get("kind") != "student" or "perception" not in state or "actor" not in state:
        raise ValueError(f"checkpoint.init: {path} holds no student policy (kind {meta.get('kind')!r}); "
                         "an oracle starts a student only as its teacher")
    mine = _student_fields(p.meta)
    check_meta(_student_fields(meta), {k: v for k, v in mine.items() if k in p.meta}, path)
    check_network(meta, p.meta, path)
    hint = "student.perception and student.preset must be the policy's"
    load_weights(p.student.perception, state["perception"], path, "perception weights", hint)
    load_weights(p.student.actor, state["actor"], path, "locomotion weights", hint)
    return {"checkpoint": str(path), "sha256": file_digest(path), "experiment": meta.get("experiment"),
            "frames": int(state.get("frames", 0)), "teacher_sha256": meta.get("teacher_sha256")}


def restore(p: UnifiedTrainer, state: dict, path, exact: bool) -> None:
    """Load a run's ``last.pt`` into the freshly built trainer ``p``.

    Args:
        state: the checkpoint (:func:`~legoh_rl.training.checkpoint.load_checkpoint`).
        path: its file, for messages.
        exact: resume (``checkpoint.resume``): every random stream continues where the checkpoint
            left it (torch, numpy, the env's, the replay window's sampling, the run's logger id).
            False for a branch (``checkpoint.branch``): networks, optimisers, VAE, curriculum,
            counters and the replay window's contents carry over, while every random stream
            keeps the one this run seeded from ``env.seed`` and the logs start a new run.

    Raises:
        CheckpointError: the checkpoint lacks training state, or was made for another robot,
            observation layout, perception or teacher (names which).
    """
    require_training_state(state, path, ("optim", "sched", "vae_optim", "critic", "vae", "env", "rng", "frames"))
    # the oracle's config is that of the teacher, which check_teacher compares by its digest
    check_meta(state["meta"], {k: v for k, v in p.meta.items()
                               if k not in ("branched_from", INIT_KEY, "oracle_config", "locomotion_network")}, path)
    check_network(state["meta"], p.meta, path)
    check_teacher(state, p.cfg, p.teacher_sha256, path)
    hint = "student.perception, student.preset and the teacher must be the ones it was trained with"
    load_weights(p.student.perception, state["perception"], path, "perception weights", hint)
    load_weights(p.student.actor, state["actor"], path, "locomotion weights", hint)
    load_weights(p.critic_nets, state["critic"], path, "critic weights", hint)
    load_weights(p.vae, state["vae"], path, "masked-VAE weights", hint)
    for key in ("optim", "vae_optim"):  # their moments, this run's fused_adam
        load_optimizer(getattr(p, key), state[key])
    p.sched.load_state_dict(state["sched"])
    p.env.load_state_dict(state["env"], streams=exact)
    if p.replay is not None and state.get("replay") is not None:
        p.replay.load_state_dict(state["replay"], stream=exact)
    elif p.replay is not None:
        print(f"{path} holds no DAgger replay window (written before windows were checkpointed, or by a "
              "run without one): it starts empty")
    if p.average is not None and exact and state.get("weight_average") is not None:
        p.average.load_state_dict(state["weight_average"])
    elif p.average is not None:  # a branch, or a run that had none: the average starts at these weights
        print(f"checkpoint.ema_decay: the weight average starts at {path}'s weights")
    if exact:
        set_rng_state(state["rng"])
        if p.generator is not None and "minibatch_rng" in state:  # else: a run that did not overlap, seeded afresh
            p.generator.set_state(state["minibatch_rng"])
        p.run_id = state.get("run_id")
    p.iteration, p.frames = state["iteration"], state["frames"]


def grad_fraction(cfg: DictConfig) -> float:
    """``encoder_grad_fraction``: the share of tick steps whose perception encoder runs (with
    gradients) in a training pass; the features recorded while acting stand in on the others."""
    return float(cfg.get("encoder_grad_fraction", 1.0))


def beta_at(iteration: int, cfg: DictConfig) -> float:
    """P(teacher acts) at an iteration: ``dagger_beta0`` decayed linearly to 0 over
    ``dagger_decay_iters`` (default: the whole DAgger phase, ``dagger_iters``). A shorter decay
    leaves a pure-DAgger stretch where the student acts and the teacher only labels."""
    decay = cfg.get("dagger_decay_iters") or cfg.dagger_iters
    return dagger_beta(iteration, float(cfg.dagger_beta0), int(decay))


def update(p: UnifiedTrainer, data, iteration: int, cfg: DictConfig) -> dict[str, float]:
    """One training step on a collected ``[N, T]`` batch; returns mean diagnostics."""
    teacher, ppo, gae, dagger, vae, hlm = p.teacher, p.ppo, p.gae, p.dagger, p.vae, p.hlm
    gen = p.generator  # collector.overlap: the update's own draws (None: torch's global generator)
    teacher.label(data)
    stats: dict[str, float] = {}

    def add(key: str, value) -> None:
        stats[key] = stats.get(key, 0.0) + float(value.detach() if torch.is_tensor(value) else value)

    # masked VAE on the teacher's actions (L_rec), its own optimiser
    flat = data.select(*vae.in_keys, strict=False).reshape(-1)  # the teacher's actions (and masks), not the depth
    for _ in range(cfg.hlm.vae_steps if cfg.hlm.enabled else 0):
        out = vae(flat[torch.randperm(flat.shape[0], generator=gen)[: min(2048, flat.shape[0])]])
        loss = sum(v for k, v in out.items() if k.startswith("loss_"))
        p.vae_optim.zero_grad()
        loss.backward()
        p.vae_optim.step()
        add("vae/loss", loss / cfg.hlm.vae_steps)
    rl = iteration >= cfg.dagger_iters
    use_hlm = cfg.hlm.enabled and iteration >= cfg.hlm.warmup_iters
    if rl:
        with torch.no_grad():
            gae(data)
    n_mb = 0
    params = [q for g in p.optim.param_groups for q in g["params"]]
    # One gather per iteration: the worlds in a random order, without the "next" entries the
    # losses no longer need (GAE is done). Minibatches are then slices (views) of it. Gathering
    # per minibatch copied ~165 MB of depth stacks into fresh pages each time, ~28% of a profiled
    # CPU run (BENCHMARKS.md, "Unified training: minibatches without copies").
    minibatches = int(cfg.ppo.num_minibatches if rl else cfg.get("dagger_minibatches") or cfg.ppo.num_minibatches)
    strided = cfg.get("minibatch_split", "permute") == "strided"
    train = data.exclude("next")
    if minibatches > 1 and not strided:  # one minibatch holds every world: no order to draw (and no copy)
        train = train[torch.randperm(data.shape[0], generator=gen)]
    size = -(-data.shape[0] // minibatches)
    for _ in range(cfg.ppo.num_epochs if rl else int(cfg.dagger_epochs)):
        # strided: minibatch j is worlds j, j + M, j + 2M, ... (views, no copy; each spans the
        # categories, which sit in contiguous blocks of worlds), in a random order each epoch
        parts = ([train[int(j)::minibatches] for j in torch.randperm(minibatches, generator=gen)] if strided else
                 [train[start : start + size] for start in range(0, data.shape[0], size)])
        for mb in parts:
            student_pass(p.student, mb, grad_fraction(cfg), gen)
            terms = {k: v for k, v in dagger(mb).items() if k.startswith("loss_")}
            if use_hlm:
                terms.update({k: v for k, v in hlm(mb).items() if k.startswith("loss_")})
            if rl:
                out = ppo(mb)
                for k in ("loss_objective", "loss_critic", "loss_entropy"):
                    terms[k] = cfg.ppo.weight * out[k]
            total = sum(terms.values())
            p.optim.zero_grad()
            total.backward()
            torch.nn.utils.clip_grad_norm_(params, cfg.ppo.max_grad_norm)
            p.optim.step()
            if rl:
                with torch.no_grad():
                    add("train/kl", policy_kl(p.student.actor, mb))
            for k, v in terms.items():
                add(f"loss/{k[5:]}", v)
            n_mb += 1
    stats = {k: v / n_mb if not k.startswith("vae/") else v for k, v in stats.items()}
    if p.replay is not None:  # extra locomotion steps on the last dagger_replay.capacity steps
        p.replay.extend(data)
        stats["loss/replay_im_action"] = p.replay.train(p.optim, cfg.ppo.max_grad_norm)
    if rl:
        stats["train/lr"] = p.sched.step(stats["train/kl"])
        stats["train/explained_variance"] = explained_variance(data["state_value"], data["value_target"])
    stats["train/phase_rl"] = float(rl)
    stats["train/hlm_on"] = float(use_hlm)
    join_std = cfg.student.get("ppo_join_std")
    if join_std is not None and iteration == cfg.dagger_iters - 1:  # the DAgger phase's last update
        stats["train/ppo_join_std"] = set_action_std(p.student.actor, float(join_std))
    return stats


def train(cfg: DictConfig) -> dict:
    """Run the unified training described by ``cfg`` (:func:`legoh_rl.training.runner.train`);
    returns a summary of the last iteration (with ``interrupted``: the signal number, when
    SIGINT/SIGTERM stopped it after a checkpoint)."""
    return runner.train(cfg, validate, build)


@hydra.main(config_path="config", config_name="unified", version_base=None)
def main(cfg: DictConfig) -> None:
    runner.finish(run_experiment(cfg, train, "unified"))


if __name__ == "__main__":
    main()
