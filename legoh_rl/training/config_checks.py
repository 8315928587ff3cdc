"""A recipe's settings checked by kind before any work: each refusal names the key and the value.

Every recipe's ``validate`` runs :func:`check_known_keys` (a key its config does not have, added
with ``+key=...``, in an experiment's yaml or in a stage's overrides, is refused instead of
ignored) and :func:`check_settings` with a table ``{dotted key: kind}``, kinds being
:class:`Integer`, :class:`Number`, :class:`Flag`, :class:`Choice`, :class:`Name` and
:class:`ListOf`. A setting absent from the config is left alone (its reader's default applies);
the checks say nothing about how settings combine, which the recipes check themselves.

    check_settings(cfg, {"ppo.gamma": Number(0, 1), "env.levels": ListOf(Integer(0, 4))})
    # ValueError: ppo.gamma must be a number in [0, 1], got 1.5
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

from omegaconf import DictConfig, ListConfig, OmegaConf
from omegaconf.errors import InterpolationResolutionError

__all__ = ["Integer", "Number", "Flag", "Choice", "Name", "ListOf", "check_settings", "check_known_keys",
           "recipe_keys"]

_ABSENT = object()


def _is_int(value) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _is_number(value) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


@dataclass(frozen=True)
class Integer:
    """An integer (not a bool, not 2.0) in ``[minimum, maximum]`` (``maximum`` None: no bound);
    null too when ``nullable``; ``text``: the message's words for it instead of the default's
    (``">= 0 (0: off)"``)."""

    minimum: int = 1
    maximum: int | None = None
    nullable: bool = False
    text: str | None = None

    def describe(self) -> str:
        if self.text:
            return self.text
        if self.maximum is not None:
            return f"an integer in [{self.minimum}, {self.maximum}]"
        return "a positive integer" if self.minimum == 1 else f"an integer >= {self.minimum}"

    def accepts(self, value) -> bool:
        return _is_int(value) and value >= self.minimum and (self.maximum is None or value <= self.maximum)


@dataclass(frozen=True)
class Number:
    """A finite number (an int or a float, not a bool) between ``low`` and ``high`` (None: no
    bound; ``*_open``: the bound itself excluded); null too when ``nullable``."""

    low: float | None = None
    high: float | None = None
    low_open: bool = False
    high_open: bool = False
    nullable: bool = False

    def describe(self) -> str:
        if self.low is not None and self.high is not None:
            return f"a number in {'(' if self.low_open else '['}{self.low}, {self.high}{')' if self.high_open else ']'}"
        if self.low is not None:
            return ("a positive number" if self.low == 0 and self.low_open
                    else f"a number {'>' if self.low_open else '>='} {self.low}")
        if self.high is not None:
            return f"a number {'<' if self.high_open else '<='} {self.high}"
        return "a finite number"

    def accepts(self, value) -> bool:
        if not _is_number(value) or not math.isfinite(value):
            return False
        if self.low is not None and (value <= self.low if self.low_open else value < self.low):
            return False
        return self.high is None or (value < self.high if self.high_open else value <= self.high)


@dataclass(frozen=True)
class Flag:
    """``true`` or ``false`` (not 0/1, not a string); null too when ``nullable``."""

    nullable: bool = False

    def describe(self) -> str:
        return "true or false"

    def accepts(self, value) -> bool:
        return isinstance(value, bool)


@dataclass(frozen=True)
class Choice:
    """One of ``choices`` (strings); null too when ``nullable``; ``what``: the noun of the message
    (``env.robot: unknown robot 'atlas'; valid: [...]``; without: ``unknown <key> 'atlas'``)."""

    choices: tuple[str, ...]
    nullable: bool = False
    what: str | None = None

    def describe(self) -> str:
        return f"one of {list(self.choices)}"

    def accepts(self, value) -> bool:
        return isinstance(value, str) and value in self.choices


@dataclass(frozen=True)
class Name:
    """Free text: a name or a path (a string, or a number as YAML reads ``2024``; not a bool, a
    list or a mapping; not empty); null too when ``nullable``. What it names is checked where it
    is used (a checkpoint path exists, ...)."""

    nullable: bool = False

    def describe(self) -> str:
        return "a non-empty string"

    def accepts(self, value) -> bool:
        return (isinstance(value, str) and value.strip() != "") or _is_number(value)


@dataclass(frozen=True)
class ListOf:
    """A list of ``item`` (``nonempty``: at least one); ``single``: one bare item stands for a
    list of it (``env.categories=gap``); null too when ``nullable``."""

    item: Integer | Number | Choice | Name
    nonempty: bool = True
    single: bool = False
    nullable: bool = False

    def describe(self) -> str:
        items = (f"names from {list(self.item.choices)}" if isinstance(self.item, Choice)
                 else _plural(self.item.describe()))
        return f"a {'non-empty ' if self.nonempty else ''}list of {items}"

    def accepts(self, value) -> bool:
        if self.single and self.item.accepts(value):
            return True
        if not isinstance(value, list | tuple):
            return False
        return (len(value) > 0 or not self.nonempty) and all(self.item.accepts(v) for v in value)


def _plural(text: str) -> str:
    """``a positive integer`` -> ``positive integers``; ``one of [...]`` stays."""
    for article in ("a ", "an "):
        if text.startswith(article):
            text = text[len(article):]
            for noun in ("integer", "number", "string"):
                if noun in text:
                    return text.replace(noun, noun + "s", 1)
    return text


Kind = Integer | Number | Flag | Choice | Name | ListOf


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
        if value is _ABSENT or (value is None and kind.nullable) or kind.accepts(value):
            continue
        raise ValueError(_refusal(key, kind, value))


def _refusal(key: str, kind: Kind, value) -> str:
    """Why ``value`` is not a ``kind``: the message of :func:`check_settings`."""
    null = " or null" if kind.nullable else ""
    if isinstance(kind, Choice):  # the project's wording for a name off a list
        if kind.what:
            return f"{key}: unknown {kind.what} {value!r}; valid: {list(kind.choices)}{null}"
        return f"unknown {key} {value!r}; valid: {list(kind.choices)}{null}"
    detail = ""
    if isinstance(kind, ListOf) and isinstance(value, list | tuple):
        bad = [v for v in value if not kind.item.accepts(v)]
        if bad and isinstance(kind.item, Choice) and kind.item.what and isinstance(bad[0], str):
            return f"{key}: unknown {kind.item.what} {bad[0]!r}; valid: {list(kind.item.choices)}"
        detail = f": {bad[0]!r} is not {kind.item.describe()}" if bad else ""
    return f"{key} must be {kind.describe()}, got {value!r}{detail}{' (or null)' if kind.nullable else ''}"


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


def recipe_keys(config_file: str | Path, sections: Mapping | None = None) -> dict:
    """The settings of a recipe's yaml (``recipes/config/<recipe>.yaml``) as a nested dict, its
    ``defaults`` list left out and ``sections`` (e.g. ``{"env": env_defaults()}``, what the
    defaults list brings in) merged over it."""
    raw = OmegaConf.to_container(OmegaConf.load(config_file), resolve=False)
    raw.pop("defaults", None)
    for key, section in (sections or {}).items():
        mine = raw.get(key) or {}
        raw[key] = {**section, **mine} if isinstance(mine, Mapping) else mine
    return raw
