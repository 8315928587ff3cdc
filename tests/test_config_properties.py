"""Every bad config value is refused, naming its key, before any work (issue 50, property test).

For each recipe (``recipes/config/*.yaml``: ``oracle_ppo``, ``unified``, ``evaluate`` and
``play``), hypothesis draws for every leaf of the composed config a
value its kind does not allow (a wrong type: text, a list, a mapping, a bool, null where null is
not a setting, a fraction for an integer; a number out of range, nan, inf; a name off its list; a
list with one bad entry) and for every section a key it does not have. Each is applied to a tiny
valid config, and the recipe is run as its command line runs it (``run_experiment`` ->
``train``; ``evaluate``; ``play``) with ``HikingEnv`` made to raise: the run must stop with a
``ValueError`` whose message names the key, before an env is built and before its output folder
exists.

:data:`KINDS` is this test's own statement of what each setting allows (independent of the
recipes' tables), but for the ``env`` and ``ppo`` sections, whose kinds are stated once, in their
dataclasses' fields (:func:`dataclass_kinds`; ``tests/test_config_store.py`` pins some by hand): a
leaf missing from it fails the test, so a new setting needs its kind here.
The counts of values tried and refused are printed at the end of the module (``-s``, or the
terminal summary).
"""

import contextlib
import dataclasses
import math
import re
import shutil
import sys
from collections import Counter
from pathlib import Path
from unittest import mock

import pytest
from hydra import compose, initialize_config_dir
from omegaconf import DictConfig, OmegaConf, open_dict

hypothesis = pytest.importorskip("hypothesis")  # the dev extra (pyproject.toml)
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from legoh_rl.envs.config import HikingEnvConfig  # noqa: E402
from legoh_rl.envs.hiking import HikingEnv  # noqa: E402
from legoh_rl.envs.rewards import REWARD_FUNCTIONS  # noqa: E402
from legoh_rl.envs.robots import ROBOTS  # noqa: E402
from legoh_rl.kinds import Choice, Flag, Integer, ListOf, MapOf, Name, Number, OneOf, field_kind  # noqa: E402
from legoh_rl.modules.locomotion import LOCOMOTION_NETWORKS  # noqa: E402
from legoh_rl.modules.oracle import ORACLE_NETWORKS  # noqa: E402
from legoh_rl.modules.perception import PERCEPTION_BUILDERS  # noqa: E402
from legoh_rl.objectives.ppo import PPOConfig  # noqa: E402
from legoh_rl.training.config_store import SET_BY_RECIPE, register_configs  # noqa: E402
from legoh_rl.training.stages import run_experiment  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "recipes" / "config"
sys.path.insert(0, str(ROOT / "recipes"))
import oracle_ppo  # noqa: E402
import play  # noqa: E402
import unified  # noqa: E402

from legoh_rl.training import eval_run  # noqa: E402

register_configs()

#: examples per recipe; each draws one bad value for every leaf and one unknown key per section
EXAMPLES = 3
CATEGORIES = ("randommix", "ditch", "hurdle", "gap", "forest", "hill")


# ------------------------------------------------------------------------------- bad values by kind

def _not_a_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return True
    return False


TEXT = st.text(max_size=8).filter(_not_a_number)  # evaluate.py reads "3" as 3 on purpose
LISTS = st.lists(st.one_of(st.integers(-3, 3), TEXT), max_size=3)
DICTS = st.dictionaries(st.from_regex(r"[a-z]{1,4}", fullmatch=True), st.integers(-3, 3), min_size=1, max_size=2)
BOOLS = st.booleans()
FRACTIONS = st.floats(allow_nan=False, allow_infinity=False, min_value=-1e6, max_value=1e6).filter(
    lambda x: not x.is_integer())
NON_FINITE = st.sampled_from([math.nan, math.inf, -math.inf])


def _with_null(parts: list, null: bool) -> st.SearchStrategy:
    return st.one_of(*parts, *([] if null else [st.none()]))


def bad_int(low: int, high: int | None = None, null: bool = False) -> st.SearchStrategy:
    """Not an integer in [low, high]: text, lists, mappings, bools, fractions, null, out of range."""
    parts = [TEXT, LISTS, DICTS, BOOLS, FRACTIONS, NON_FINITE, st.integers(max_value=low - 1)]
    if high is not None:
        parts.append(st.integers(min_value=high + 1))
    return _with_null(parts, null)


def bad_num(low=None, high=None, low_open=False, high_open=False, null=False) -> st.SearchStrategy:
    """Not a finite number in the range: text, lists, mappings, bools, null, nan, inf, out of range."""
    parts = [TEXT, LISTS, DICTS, BOOLS, NON_FINITE]
    if low is not None:
        parts.append(st.floats(max_value=low, exclude_max=not low_open, allow_nan=False, allow_infinity=False,
                               min_value=-1e6))
    if high is not None:
        parts.append(st.floats(min_value=high, exclude_min=not high_open, allow_nan=False, allow_infinity=False,
                               max_value=1e6))
    return _with_null(parts, null)


def bad_flag(null: bool = False) -> st.SearchStrategy:
    """Not true/false: text, numbers, lists, mappings, null."""
    return _with_null([st.text(max_size=6), st.integers(-2, 2), FRACTIONS, LISTS, DICTS], null)


def bad_choice(choices, null: bool = False) -> st.SearchStrategy:
    """Not one of ``choices``: other text, numbers, lists, mappings, bools, null."""
    return _with_null([st.text(max_size=8).filter(lambda t: t not in choices), st.integers(-2, 2), LISTS, DICTS,
                       BOOLS], null)


def bad_name(null: bool = False) -> st.SearchStrategy:
    """Not a name or a path: lists, mappings, bools, empty text, null."""
    return _with_null([LISTS, DICTS, BOOLS, st.sampled_from(["", "  "])], null)


def bad_list(good_item, bad_item, null: bool = False, single_ok=()) -> st.SearchStrategy:
    """Not a non-empty list of good items: a bare scalar (but ``single_ok``), a mapping, a bool,
    null, ``[]``, or good items with one bad one."""
    with_bad = st.tuples(st.lists(good_item, max_size=2), bad_item, st.integers(0, 2)).map(
        lambda t: t[0][:t[2]] + [t[1]] + t[0][t[2]:])
    bare = st.one_of(TEXT.filter(lambda t: t not in single_ok), st.integers(-3, 3), FRACTIONS)
    return _with_null([bare, DICTS, BOOLS, st.just([]), with_bad], null)


def bad_device() -> st.SearchStrategy:
    """Not auto | cpu | cuda[:i] (null is auto): other text, numbers, lists, mappings, bools."""
    devices = re.compile(r"\s*(auto|cpu|cuda(:\d+)?)\s*", re.IGNORECASE)
    return st.one_of(st.text(max_size=8).filter(lambda t: not devices.fullmatch(t)), st.integers(-2, 2), LISTS,
                     DICTS, BOOLS)


def bad_stages() -> st.SearchStrategy:
    """Not a mapping of stages (null: none): text, numbers, lists, bools."""
    return st.one_of(TEXT, st.integers(-3, 3), LISTS, BOOLS)


# ------------------------------------------------------------------------------- what each key allows

def bad_of(kind) -> st.SearchStrategy:
    """Values a field's kind (legoh_rl/kinds.py) does not allow: the strategies above, by kind."""
    null = kind.nullable
    if isinstance(kind, Integer):
        return bad_int(kind.minimum, kind.maximum, null=null)
    if isinstance(kind, Number):
        return bad_num(kind.low, kind.high, kind.low_open, kind.high_open, null=null)
    if isinstance(kind, Flag):
        return bad_flag(null=null)
    if isinstance(kind, Choice):
        return bad_choice(kind.options, null=null)
    if isinstance(kind, Name):
        return bad_name(null=null)
    if isinstance(kind, ListOf):
        item = kind.item
        good = (st.sampled_from(item.options) if isinstance(item, Choice) else
                st.integers(item.minimum, item.maximum if item.maximum is not None else item.minimum + 3)
                if isinstance(item, Integer) else st.floats(0.05, 2))
        return bad_list(good, bad_of(item), null=null, single_ok=item.options if kind.single else ())
    if isinstance(kind, OneOf):  # eval_domain_rand: true, false, a term or a list of terms
        terms = next(k.options for k in kind.kinds if isinstance(k, Choice))
        return st.one_of(TEXT.filter(lambda t: t not in terms), st.integers(-2, 2), FRACTIONS, DICTS, st.none(),
                         st.just([]), st.lists(TEXT.filter(lambda t: t not in terms), min_size=1, max_size=2))
    raise AssertionError(f"no strategy for {kind}")


def map_kinds(prefix: str, kind: MapOf) -> dict:
    """``{"<prefix>.<name>": bad values}`` for two valid names of a mapping (the recipes' reward
    terms ``alive`` and ``termination``, the categories ``gap`` and ``ditch``), a nested mapping's
    entries one level down."""
    names = [n for n in ("alive", "termination", "gap", "ditch") if n in kind.key.options]
    out = {}
    for name in names:
        if isinstance(kind.value, MapOf):
            out.update(map_kinds(f"{prefix}.{name}", kind.value))
        else:
            out[f"{prefix}.{name}"] = bad_of(kind.value)
    return out


def dataclass_kinds(section: str, cls, skip=()) -> dict:
    """``{"<section>.<field>": bad values}`` for every field of a config dataclass (nested
    sections' fields as ``<section>.<sub>.<field>``), read from the kinds its fields state."""
    out = {}
    for f in dataclasses.fields(cls):
        if f.name in skip:
            continue
        kind = field_kind(f)
        if kind is None:  # a nested section
            out.update(dataclass_kinds(f"{section}.{f.name}", type(f.default_factory())))
        elif isinstance(kind, MapOf):  # reward_overrides, category_reward_scales: entries by the value's kind
            out.update(map_kinds(f"{section}.{f.name}", kind))
        else:
            out[f"{section}.{f.name}"] = bad_of(kind)
    return out


#: the env and ppo sections: every field of HikingEnvConfig (but what the recipe sets) and of
#: PPOConfig, by the kinds the fields state (tests/test_config_store.py pins a few of them)
ENV = dataclass_kinds("env", HikingEnvConfig, skip=SET_BY_RECIPE)
TRAINING = {
    **ENV,
    **dataclass_kinds("ppo", PPOConfig),
    "experiment_name": bad_name(null=True),
    "stage_name": bad_name(null=True),
    "stages": bad_stages(),
    "device": bad_device(),
    "collector.steps_per_env": bad_int(1),
    "collector.total_frames": bad_int(1),
    "collector.workers": bad_int(1),
    "collector.allow_new_workers": bad_flag(),
    "collector.overlap": bad_flag(),
    "collector.backend": bad_choice(("local", "ray")),
    "collector.ray.address": bad_name(null=True),
    "collector.ray.num_cpus_per_worker": bad_int(1),
    "collector.ray.memory_per_worker_gib": bad_num(0, low_open=True, null=True),
    "logger.backend": bad_choice(("wandb", "csv")),
    "logger.online": bad_flag(),
    "logger.project": bad_name(),
    "logger.exp_name": bad_name(),
    "logger.group": bad_name(null=True),
    "logger.log_every": bad_int(1),
    "logger.video_every": bad_int(0, null=True),
    "logger.video_seconds": bad_num(0, low_open=True),
    "checkpoint.dir": bad_name(),
    "checkpoint.every": bad_int(1),
    "checkpoint.snapshot_every": bad_int(0, null=True),
    "checkpoint.resume": bad_name(null=True),
    "checkpoint.keep_curriculum": bad_flag(),
    "checkpoint.overwrite": bad_flag(),
    "torch_threads": bad_int(1),
    "fused_adam": bad_flag(),
}
KINDS = {
    "oracle_ppo": {
        **TRAINING,
        "recipe": bad_choice(("oracle_ppo",), null=True),
        "model.init_std": bad_num(0, low_open=True),
        "model.max_std": bad_num(0, low_open=True, null=True),
        "model.start_std": bad_num(0, low_open=True, null=True),
        "model.network": bad_choice(tuple(ORACLE_NETWORKS)),
        "model.layers": bad_list(st.integers(1, 64), bad_int(1), null=True),
        "checkpoint.init": bad_name(null=True),
        "checkpoint.init_widen": bad_flag(),
        "checkpoint.init_curriculum": bad_flag(),
        "feedforward_anneal": bad_list(st.integers(0, 10), bad_int(0), null=True, single_ok=("inherit",)),
        "update_threads": bad_int(1, null=True),
        "kl_measure": bad_choice(("after_step", "loss_forward")),
    },
    "unified": {
        **TRAINING,
        "recipe": bad_choice(("unified",), null=True),
        "teacher": bad_name(),
        "student.perception": bad_choice(tuple(PERCEPTION_BUILDERS)),
        "student.preset": bad_choice(("cpu", "paper")),
        "student.init_std": bad_num(0, low_open=True, null=True),
        "student.ppo_join_std": bad_num(0, low_open=True, null=True),
        "student.locomotion": bad_choice(("learned", "oracle")),
        "student.network": bad_choice(tuple(LOCOMOTION_NETWORKS)),
        "dagger_iters": bad_int(0),
        "dagger_beta0": bad_num(0, 1),
        "dagger_decay_iters": bad_int(1, null=True),
        "dagger_epochs": bad_int(1),
        "encoder_grad_fraction": bad_num(0, 1, low_open=True),
        "dagger_minibatches": bad_int(1, null=True),
        "minibatch_split": bad_choice(("permute", "strided")),
        "dagger_replay.capacity": bad_int(0),
        "dagger_replay.batch_size": bad_int(1),
        "dagger_replay.steps": bad_int(1),
        "ppo.weight": bad_num(0),
        **{f"imitation.{w}": bad_num(0) for w in ("w1", "w2", "w3", "w_priv")},
        "hlm.enabled": bad_flag(),
        "hlm.vanilla_vae": bad_flag(),
        **{f"hlm.{w}": bad_num(0) for w in ("w4", "w5", "w6", "w7", "w8", "c_mt", "c_ms")},
        "hlm.mask_ratio": bad_num(0, 1, high_open=True),
        "hlm.vae_lr": bad_num(0, low_open=True),
        "hlm.vae_steps": bad_int(1),
        "hlm.warmup_iters": bad_int(0),
        "checkpoint.branch": bad_name(null=True),
        "checkpoint.init": bad_name(null=True),
        "checkpoint.ema_decay": bad_num(0, 1, low_open=True, high_open=True, null=True),
        "allow_new_teacher": bad_flag(),
    },
    "evaluate": {
        "checkpoint": bad_name(),
        "robot": bad_choice(("h1", "g1")),
        "categories": bad_list(st.sampled_from(CATEGORIES), bad_choice(CATEGORIES)),
        "levels": bad_list(st.integers(0, 4), bad_int(0, 4)),
        "protocol": bad_choice(("cpu", "paper")),
        "robots_per_cell": bad_int(1),
        "runs": bad_int(1),
        "variants": bad_int(1),
        "seed": bad_int(0),
        "trail_seeds": bad_list(st.integers(0, 99), bad_int(0), null=True),
        "num_threads": bad_int(1, null=True),
        "physics": bad_choice(("mujoco", "warp")),
        "domain_rand": st.one_of(TEXT, st.integers(-2, 2), FRACTIONS, DICTS, st.none(), st.just([]),
                                 st.lists(st.text(max_size=6).filter(lambda t: t not in (
                                     "friction", "base_mass", "base_com", "motor_strength", "push", "action_delay")),
                                     min_size=1, max_size=2)),
        "device": bad_device(),
        "output_dir": bad_name(),
        "overwrite": bad_flag(),
        "video": bad_flag(),
        "video_seconds": bad_num(0, low_open=True),
        "video_per_category": bad_flag(),
        "logger.backend": bad_choice(("wandb", "csv")),
        "logger.online": bad_flag(),
        "logger.project": bad_name(),
        "logger.exp_name": bad_name(),
        "logger.group": bad_name(null=True),
    },
    "play": {
        "checkpoint": bad_name(),
        "robot": bad_choice(("h1", "g1"), null=True),
        "category": bad_choice(CATEGORIES),
        "level": bad_int(0, 4),
        "variant": bad_int(0),
        "num_robots": bad_int(1, 16),
        "seed": bad_int(0),
        "viewer": bad_choice(("browser", "native")),
        "host": bad_name(),
        "port": bad_int(0, 65535),
        "speed": bad_num(0, 1, low_open=True),
        "follow": bad_flag(),
        "device": bad_device(),
        "seconds": bad_num(0, low_open=True, null=True),
        "screenshot": bad_name(null=True),
        "screenshot_size": st.one_of(bad_list(st.integers(64, 2000), bad_int(64)),
                                     st.lists(st.integers(64, 2000), min_size=3, max_size=4), st.just([640])),
    },
}
#: settings no value of which is refused, with the reason: none today. (Paths are checked where
#: they are read, e.g. a missing checkpoint; this test draws only their wrong types.)
EXCLUDED: dict[str, str] = {}


# ------------------------------------------------------------------------------- the recipes, tiny

class EnvBuilt(Exception):
    """Raised in place of building a HikingEnv: the config got past every check."""


def _refuse_env(self, *args, **kwargs):
    raise EnvBuilt


def tiny(name: str, out: Path) -> DictConfig:
    """A small valid config of recipe ``name`` whose output folder is ``out`` (not created)."""
    env = ["env.num_envs=2", "env.categories=[randommix]", "env.levels=[0]", "env.variants=1", "env.num_threads=1"]
    train = ["device=cpu", "collector.steps_per_env=2", "collector.total_frames=8", "ppo.num_minibatches=1",
             "logger.backend=csv", f"checkpoint.dir={out}"]
    overrides = {
        "oracle_ppo": env + train + ["model.layers=[8]"],
        "unified": env + train + [f"teacher={ROOT / 'checkpoints' / 'oracle_h1.pt'}"],
        "evaluate": ["checkpoint=zero", "categories=[randommix]", "levels=[0]", "robots_per_cell=1", "variants=1",
                     "device=cpu", "logger.backend=csv", f"output_dir={out}"],
        "play": ["checkpoint=zero", "category=randommix", "level=0", "device=cpu", "port=0",
                 f"screenshot={out / 'page.png'}"],
    }[name]
    with initialize_config_dir(config_dir=str(CONFIG), version_base=None):
        return compose(config_name=name, overrides=overrides)


def run(name: str, cfg: DictConfig) -> None:
    """Run recipe ``name`` on ``cfg`` as its command line does."""
    if name == "evaluate":
        eval_run.evaluate(cfg)
    elif name == "play":
        play.play(cfg)
    else:
        run_experiment(cfg, {"oracle_ppo": oracle_ppo.train, "unified": unified.train}[name], name)


def leaves(cfg: DictConfig, prefix: str = "") -> list[str]:
    """The dotted keys of ``cfg``'s leaves (a section's entries, not the section)."""
    out = []
    for key in cfg:
        node = cfg._get_node(key)
        if isinstance(node, DictConfig) and not node._is_none():
            out += leaves(node, f"{prefix}{key}.")
        else:
            out.append(f"{prefix}{key}")
    return out


def sections(cfg: DictConfig, prefix: str = "") -> list[str]:
    """The dotted keys of ``cfg``'s sections ("" for the top)."""
    out = [prefix.rstrip(".")]
    for key in cfg:
        node = cfg._get_node(key)
        if isinstance(node, DictConfig) and not node._is_none():
            out += sections(node, f"{prefix}{key}.")
    return out


def with_value(cfg: DictConfig, key: str, value) -> DictConfig:
    """A copy of ``cfg`` with ``key`` set to ``value`` (added when new, as ``+key=`` does)."""
    out = cfg.copy()
    with open_dict(out):
        OmegaConf.update(out, key, value, merge=False, force_add=True)
    return out


def expect_refused(name: str, cfg: DictConfig, key: str, value, out: Path, names: str) -> None:
    """``cfg`` (``key`` = ``value``) must be refused with a ValueError naming ``names``, before an
    env is built and before ``out`` exists (removed again whatever happened, so one accepted value
    does not fail the next)."""
    try:
        run(name, cfg)
    except EnvBuilt:
        raise AssertionError(f"{name}: {key}={value!r} was accepted: an env was being built") from None
    except ValueError as err:
        assert names in str(err), f"{name}: {key}={value!r} was refused without naming {names!r}: {err}"
    else:
        raise AssertionError(f"{name}: {key}={value!r} was accepted")
    finally:
        made = out.exists()
        shutil.rmtree(out, ignore_errors=True)
    assert not made, f"{name}: {key}={value!r} was refused after {out} was made"


COUNTS: Counter = Counter()


@pytest.fixture(scope="module", autouse=True)
def report(request):
    """Print how many bad values each recipe was given and refused."""
    yield
    lines = [f"config property test: {name}: {COUNTS[name, 'tried']} bad values tried, "
             f"{COUNTS[name, 'refused']} refused naming the key ({COUNTS[name, 'keys']} leaves, "
             f"{COUNTS[name, 'unknown']} unknown keys)" for name in KINDS if COUNTS[name, "tried"]]
    capture = request.config.pluginmanager.get_plugin("capturemanager")
    with capture.global_and_fixture_disabled() if capture is not None else contextlib.nullcontext():
        print("\n" + "\n".join(lines))


@pytest.fixture(scope="module")
def folders(tmp_path_factory):
    return tmp_path_factory.mktemp("config_properties")


@pytest.mark.parametrize("name", ["oracle_ppo", "unified", "evaluate", "play"])
def test_every_bad_value_is_refused_naming_its_key_before_any_work(name, folders):
    out = folders / name / "never"
    base = tiny(name, out)
    missing = sorted(set(leaves(base)) - set(KINDS[name]) - set(EXCLUDED))
    assert not missing, f"{name}: settings without a kind in this test's KINDS (add them): {missing}"
    keys = [k for k in leaves(base) if k not in EXCLUDED]
    known = {s: set(OmegaConf.select(base, s).keys() if s else base.keys()) for s in sections(base)}
    with mock.patch.object(HikingEnv, "__init__", _refuse_env):
        with pytest.raises(EnvBuilt):  # the tiny config itself is valid: it gets as far as the env
            run(name, tiny(name, folders / name / "valid"))

        @settings(max_examples=EXAMPLES, deadline=None, derandomize=True, database=None,
                  suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
        @given(data=st.data())
        def every_key(data):
            for key in keys:
                value = data.draw(KINDS[name][key], label=key)
                COUNTS[name, "tried"] += 1
                expect_refused(name, with_value(base, key, value), key, value, out, key)
                COUNTS[name, "refused"] += 1
            for section, have in known.items():
                if section == "env.reward_overrides":  # a mapping of reward terms: a new term must be one
                    have = have | set(REWARD_FUNCTIONS)
                if section == "checkpoints":  # play's {robot: checkpoint}: a new key must be a robot
                    have = have | set(ROBOTS)
                new = data.draw(st.from_regex(r"[a-z][a-z0-9_]{0,9}", fullmatch=True).filter(lambda k, have=have: k not in have),
                                label=f"new key in {section or 'the top'}")
                key = f"{section}.{new}" if section else new
                COUNTS[name, "tried"] += 1
                COUNTS[name, "unknown"] += 1
                expect_refused(name, with_value(base, key, 1), key, 1, out, new)
                COUNTS[name, "refused"] += 1

        every_key()
    COUNTS[name, "keys"] = len(keys)

