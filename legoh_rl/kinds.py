"""Kinds of settings, stated once in the config dataclasses' fields, and the checks that use them.

A config dataclass (``HikingEnvConfig``, ``PPOConfig``, their nested sections) declares each
field with :func:`setting`, which records what values the field allows as a *kind*
(:class:`Integer`, :class:`Number`, :class:`Flag`, :class:`Choice`, :class:`Name`,
:class:`ListOf`, :class:`MapOf`, :class:`OneOf`)::

    @dataclass
    class Example:
        steps: int = setting(4, Integer(1))
        noise: float = setting(0.0, Number(0))

        def __post_init__(self):
            check_fields(self)  # ValueError: steps must be a positive integer, got 0

The same kinds check a recipe's section before the dataclass is built (:func:`build_section`,
``where="env"``: ``env.steps must be a positive integer, got 0``) and give hydra the section's
defaults (:func:`section_defaults`), so a field's default and its allowed values are written once.
This module imports nothing from the project: envs, objectives and training all read it.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass

__all__ = ["Integer", "Number", "Flag", "Choice", "Name", "ListOf", "MapOf", "OneOf", "Kind", "setting",
           "field_kind", "refusal", "check_fields", "build_section", "section_defaults"]


def _is_int(value) -> bool:
    return isinstance(value, numbers.Integral) and not isinstance(value, bool)


def _is_number(value) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, bool)


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
    (``env.robot: unknown robot 'atlas'; valid: [...]``; without: ``unknown <key> 'atlas'``).

    ``choices`` may be a callable returning them, read at each check: a registry (a dict of
    builders) whose later entries are then valid too.
    """

    choices: tuple[str, ...] | Callable[[], Iterable[str]]
    nullable: bool = False
    what: str | None = None

    @property
    def options(self) -> tuple[str, ...]:
        """The valid names now."""
        return tuple(self.choices() if callable(self.choices) else self.choices)

    def describe(self) -> str:
        return f"one of {list(self.options)}"

    def accepts(self, value) -> bool:
        return isinstance(value, str) and value in self.options


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
    """A list of ``item`` (``nonempty``: at least one; ``length``: exactly that many); ``single``:
    one bare item stands for a list of it (``env.categories=gap``); null too when ``nullable``."""

    item: Integer | Number | Choice | Name
    nonempty: bool = True
    single: bool = False
    nullable: bool = False
    length: int | None = None

    def describe(self) -> str:
        items = (f"names from {list(self.item.options)}" if isinstance(self.item, Choice)
                 else _plural(self.item.describe()))
        if self.length is not None:
            return f"a list of {self.length} {items}"
        return f"a {'non-empty ' if self.nonempty else ''}list of {items}"

    def accepts(self, value) -> bool:
        if self.single and self.item.accepts(value):
            return True
        if not isinstance(value, list | tuple):
            return False
        if self.length is not None and len(value) != self.length:
            return False
        return (len(value) > 0 or not self.nonempty) and all(self.item.accepts(v) for v in value)


@dataclass(frozen=True)
class MapOf:
    """A mapping of names ``key`` (a :class:`Choice`) to values ``value`` (e.g. reward term ->
    weight); each entry is checked and named as ``<key>.<name>``; null too when ``nullable``."""

    key: Choice
    value: Integer | Number | Flag | Name
    nullable: bool = False

    def describe(self) -> str:
        return f"a mapping of {self.key.what or 'name'} -> {self.value.describe()}"

    def accepts(self, value) -> bool:
        return isinstance(value, Mapping) and all(self.key.accepts(k) and self.value.accepts(v)
                                                  for k, v in value.items())


@dataclass(frozen=True)
class OneOf:
    """Any of ``kinds`` (e.g. ``true``/``false`` or a list of term names); ``text``: the message's
    words for it."""

    kinds: tuple
    text: str
    nullable: bool = False

    def describe(self) -> str:
        return self.text

    def accepts(self, value) -> bool:
        return any(kind.accepts(value) for kind in self.kinds)


Kind = Integer | Number | Flag | Choice | Name | ListOf | MapOf | OneOf


def _plural(text: str) -> str:
    """``a positive integer`` -> ``positive integers``; ``one of [...]`` stays."""
    for article in ("a ", "an "):
        if text.startswith(article):
            text = text[len(article):]
            for noun in ("integer", "number", "string"):
                if noun in text:
                    return text.replace(noun, noun + "s", 1)
    return text


def refusal(key: str, kind: Kind, value) -> str | None:
    """Why ``value`` of setting ``key`` is not a ``kind`` (None: it is, or it is null where null
    is a setting). The one wording of every refusal: ``<key> must be <kind>, got <value>``; for
    a :class:`Choice`, ``unknown <key> <value>; valid: [...]``; a list or mapping names its first
    bad entry."""
    if (value is None and kind.nullable) or kind.accepts(value):
        return None
    null = " or null" if kind.nullable else ""
    if isinstance(kind, Choice):  # the project's wording for a name off a list
        if kind.what:
            return f"{key}: unknown {kind.what} {value!r}; valid: {list(kind.options)}{null}"
        return f"unknown {key} {value!r}; valid: {list(kind.options)}{null}"
    if isinstance(kind, OneOf) and isinstance(value, list | tuple) and value:  # a list's first bad entry
        for option in kind.kinds:
            if isinstance(option, ListOf):
                return refusal(key, option, value)
    if isinstance(kind, MapOf) and isinstance(value, Mapping):
        for name, entry in value.items():
            if not kind.key.accepts(name):
                return f"{key}.{name}: unknown {kind.key.what or 'name'}; known: {sorted(kind.key.options)}"
            if not kind.value.accepts(entry):
                return f"{key}.{name} must be {kind.value.describe()}, got {entry!r}"
    detail = ""
    if isinstance(kind, ListOf) and isinstance(value, list | tuple):
        bad = [v for v in value if not kind.item.accepts(v)]
        if bad and isinstance(kind.item, Choice) and kind.item.what and isinstance(bad[0], str):
            return f"{key}: unknown {kind.item.what} {bad[0]!r}; valid: {list(kind.item.options)}"
        detail = f": {bad[0]!r} is not {kind.item.describe()}" if bad else ""
    return f"{key} must be {kind.describe()}, got {value!r}{detail}{null and ' (or null)'}"


def setting(default, kind: Kind, *, factory: Callable | None = None):
    """A dataclass field with ``default`` (or ``factory()`` for a mutable or nested default) whose
    values must be a ``kind`` (:func:`check_fields`)."""
    if factory is not None:
        return dataclasses.field(default_factory=factory, metadata={"kind": kind})
    return dataclasses.field(default=default, metadata={"kind": kind})


def field_kind(f: dataclasses.Field) -> Kind | None:
    """The kind :func:`setting` gave field ``f`` (None: a nested section or a plain field)."""
    return f.metadata.get("kind")


def _section(f: dataclasses.Field):
    """The dataclass of a nested section field (its default's type), else None."""
    if f.default_factory is not dataclasses.MISSING:
        value = f.default_factory()
        return type(value) if dataclasses.is_dataclass(value) else None
    return None


def check_fields(config, cls=None, where: str = "", skip: Iterable[str] = ()) -> None:
    """Check each field of a config against its kind: ``config`` is an instance of dataclass
    ``cls`` or a mapping of its fields (a recipe's section; nested sections as mappings).

    Args:
        where: the section's dotted name, prefixed to each key in messages (``"env"``).
        skip: fields not checked (set by the caller, e.g. the recipe's ``device``).

    Raises:
        ValueError: the first bad value (``<where>.<field> must be ...``), or, for a mapping, a key
            that is not a field of ``cls`` (lists the fields).
    """
    cls = cls or type(config)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    prefix = f"{where}." if where else ""
    if isinstance(config, Mapping):
        unknown = [k for k in config if k not in fields or k in skip]
        if unknown:
            raise ValueError(f"{where or cls.__name__} has no setting {unknown[0]!r}: its settings are "
                             f"{sorted(k for k in fields if k not in skip)}")
        get = config.get
        names = [n for n in fields if n in config]
    else:
        get = lambda name: getattr(config, name)  # noqa: E731
        names = list(fields)
    for name in names:
        if name in skip:
            continue
        f, value = fields[name], get(name)
        nested = _section(f)
        if nested is not None:
            if isinstance(value, Mapping):
                check_fields(value, nested, f"{prefix}{name}")
            elif not isinstance(value, nested):
                names_ = [x.name for x in dataclasses.fields(nested)]
                hint = (f" ({prefix}{name}.enabled={str(value).lower()} is its switch)"
                        if isinstance(value, bool) and "enabled" in names_ else "")
                raise ValueError(f"{prefix}{name} must be a section with settings {sorted(names_)}, "
                                 f"got {value!r}{hint}")
            continue
        kind = field_kind(f)
        message = None if kind is None else refusal(f"{prefix}{name}", kind, value)
        if message:
            raise ValueError(message)


def _typed(kind: Kind | None, value):
    """A checked section value as its field holds it: lists as tuples (a bare item of a
    ``ListOf(single=True)`` as a 1-tuple), a :class:`Number`'s integers as floats (``1`` -> ``1.0``,
    as a float field's default is), mappings as dicts."""
    if value is None:
        return None
    if isinstance(kind, Number):
        return float(value)
    if isinstance(kind, ListOf):
        if kind.single and kind.item.accepts(value):
            value = [value]
        return tuple(_typed(kind.item, v) for v in value)
    if isinstance(kind, MapOf):
        return {k: _typed(kind.value, v) for k, v in value.items()}
    if isinstance(kind, OneOf) and isinstance(value, list | tuple):
        return tuple(value)
    return value


def build_section(cls, values: Mapping, where: str = "", **fixed):
    """An instance of dataclass ``cls`` from a recipe's section ``values`` (plain containers):
    checked by :func:`check_fields` first, each key named ``<where>.<key>``; nested sections
    built the same way; lists become tuples (a bare item of a ``ListOf(single=True)`` field a
    1-tuple); fields absent from ``values`` keep their defaults. ``fixed``: fields the caller sets
    (not settings of the section). A combination the dataclass refuses (its ``__post_init__``)
    is re-raised as ``<where>: <message>``.

    Raises:
        ValueError: as above.
    """
    check_fields(values, cls, where, skip=fixed)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    kwargs = {}
    for name, value in values.items():
        f = fields[name]
        nested = _section(f)
        if nested is not None and isinstance(value, Mapping):
            value = build_section(nested, value, f"{where}.{name}" if where else name)
        else:
            value = _typed(field_kind(f), value)
        kwargs[name] = value
    try:
        return cls(**kwargs, **fixed)
    except ValueError as err:
        raise ValueError(f"{where}: {err}" if where else str(err)) from None


def section_defaults(cls, skip: Iterable[str] = ()) -> dict:
    """``{field: default}`` of dataclass ``cls`` as plain containers (tuples as lists, nested
    sections as mappings), ``skip`` left out: a hydra config group's node."""

    def plain(value):
        if dataclasses.is_dataclass(value):
            return {f.name: plain(getattr(value, f.name)) for f in dataclasses.fields(value)}
        if isinstance(value, list | tuple):
            return [plain(v) for v in value]
        if isinstance(value, Mapping):
            return {k: plain(v) for k, v in value.items()}
        return value

    out = {}
    for f in dataclasses.fields(cls):
        if f.name in skip:
            continue
        value = f.default_factory() if f.default is dataclasses.MISSING else f.default
        out[f.name] = plain(value)
    return out
