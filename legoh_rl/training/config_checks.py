"""A recipe's settings checked by kind before any work: each refusal names the key and the value.

Every recipe's ``validate`` runs :func:`check_known_keys` (a key its config does not have, added
with ``+key=...``, in an experiment's yaml or in a stage's overrides, is refused instead of
ignored) and :func:`check_settings` with a table ``{dotted key: kind}`` for the settings that are
not fields of a config dataclass (the kinds are :mod:`legoh_rl.kinds`'; the ``env`` and ``ppo``
sections are checked by their dataclasses' own fields, :mod:`legoh_rl.training.config_store`). A
setting absent from the config is left alone (its reader's default applies); the checks say
nothing about how settings combine, which the recipes check themselves.

    check_settings(cfg, {"ppo.gamma": Number(0, 1), "env.levels": ListOf(Integer(0, 4))})
    # ValueError: ppo.gamma must be a number in [0, 1], got 1.5
"""

from __future__ import annotations

import copy
from collections.abc import Mapping
from functools import lru_cache
from pathlib import Path

from omegaconf import DictConfig, ListConfig, OmegaConf
from omegaconf.errors import InterpolationResolutionError

from legoh_rl.kinds import Choice, Flag, Integer, Kind, ListOf, MapOf, Name, Number, OneOf, refusal

__all__ = ["Integer", "Number", "Flag", "Choice", "Name", "ListOf", "MapOf", "OneOf", "Kind", "check_settings",
           "check_known_keys", "recipe_keys"]

_ABSENT = object()


def _plain(value):
    """A config node as plain Python (lists, dicts, scalars), interpolations resolved."""
    if isinstance(value, DictConfig | ListConfig):
        return OmegaConf.to_container(value, resolve=True)
    return value


def check_settings(cfg: Mapping, kinds: Mapping[str, Kind]) -> None:
    """Check each setting of ``kinds`` (dotted keys) that ``cfg`` has against its kind.

    Raises:
        ValueError: ``<key> must be <kind>, got <value>`` (then ``(or null)`` where null is a
            setting; for a list, the first bad entry is named too); for a :class:`Choice`,
            ``unknown <key> <value>; valid: [...]``.
    """
    for key, kind in kinds.items():
        try:
            value = _plain(OmegaConf.select(cfg, key, default=_ABSENT) if isinstance(cfg, DictConfig)
                           else _select(cfg, key))
        except InterpolationResolutionError:  # ${other.key} of a bad value: that key's own check names it
            continue
        message = None if value is _ABSENT else refusal(key, kind, value)
        if message:
            raise ValueError(message)


def _select(cfg: Mapping, key: str):
    node = cfg
    for part in key.split("."):
        if not isinstance(node, Mapping) or part not in node:
            return _ABSENT
        node = node[part]
    return node


def check_known_keys(cfg: Mapping, known: Mapping, open_sections: tuple[str, ...] = (), where: str = "",
                     name: str = "the config") -> None:
    """Refuse a key of ``cfg`` that ``known`` (the recipe's own config: :func:`recipe_keys`) does
    not have, at any depth but inside ``open_sections`` (dotted keys whose entries are free, or
    checked elsewhere).

    Raises:
        ValueError: ``<section> has no setting '<key>': its settings are [...]`` (``name`` for the
            top level); or a section given a value that is not a mapping.
    """
    for key in cfg:
        dotted = f"{where}.{key}" if where else str(key)
        if dotted in open_sections:
            continue
        if key not in known:
            raise ValueError(f"{where or name} has no setting {key!r}: its settings are {sorted(known)}")
        ref = known[key]
        if isinstance(ref, Mapping) and ref:
            value = cfg[key]
            if not isinstance(value, Mapping):
                raise ValueError(f"{dotted} must be a section with settings {sorted(ref)}, got {_plain(value)!r}")
            check_known_keys(value, ref, open_sections, dotted, name)


def recipe_keys(config_file: str | Path) -> dict:
    """The settings of a recipe's yaml (``recipes/config/<recipe>.yaml``) as a nested dict: what
    its ``defaults`` list brings in (a group's option from hydra's ConfigStore, e.g. ``env/hiking``,
    or a yaml file beside the recipe's, e.g. ``shared/training.yaml``; ``# @package _global_`` at
    the top level, else under the group's name; ``experiment`` and null options left out) with
    the recipe's own settings merged over it. A fresh copy each call; the parsed files are kept
    per process, keyed by the yaml files' modification times and sizes (a recipe validates once per run,
    a test or a stage schedule many times)."""
    config_file = Path(config_file).resolve()
    stamps = tuple((str(f), f.stat().st_mtime_ns, f.stat().st_size) for f in sorted(config_file.parent.rglob("*.yaml")))
    return copy.deepcopy(_recipe_keys(config_file, stamps))


@lru_cache(maxsize=16)
def _recipe_keys(config_file: Path, stamps: tuple) -> dict:
    """:func:`recipe_keys`' work, cached per ``(config_file, stamps)``."""
    raw = OmegaConf.to_container(OmegaConf.load(config_file), resolve=False)
    out: dict = {}
    for entry in raw.pop("defaults", None) or []:
        if not isinstance(entry, Mapping):
            continue  # _self_
        for group, option in entry.items():
            if option is None or group == "experiment":
                continue
            node, package = _group_option(config_file.parent, group, option)
            _merge(out, node if package == "_global_" else {group: node})
    _merge(out, raw)
    return out


def _group_option(config_dir: Path, group: str, option: str) -> tuple[dict, str]:
    """``(node, package)`` of a defaults-list entry: a yaml file ``<config_dir>/<group>/<option>.yaml``
    (its ``# @package`` line) or a node in hydra's ConfigStore (package: the group)."""
    path = config_dir / group / f"{option}.yaml"
    if path.is_file():
        text = path.read_text()
        first = next((line for line in text.splitlines() if line.strip()), "")
        package = first.split("@package", 1)[1].strip() if "@package" in first else group
        return OmegaConf.to_container(OmegaConf.create(text), resolve=False) or {}, package
    from hydra.core.config_store import ConfigStore

    stored = ConfigStore.instance().load(f"{group}/{option}.yaml")
    return OmegaConf.to_container(stored.node, resolve=False), stored.package or group


def _merge(into: dict, other: Mapping) -> None:
    """``other`` merged into ``into`` key by key (mappings recursively, other values replace)."""
    for key, value in other.items():
        if isinstance(value, Mapping) and isinstance(into.get(key), dict):
            _merge(into[key], value)
        else:
            into[key] = dict(value) if isinstance(value, Mapping) else value
