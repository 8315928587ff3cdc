"""Tables of things by name (networks, terrain primitives, reward terms): one way to add an entry
and one way to look one up, with the same errors everywhere.

A :class:`Registry` is a ``dict`` (iterate it, ``in``, ``reg[name]``, ``sorted(reg)`` as
before) that adds :meth:`Registry.register` (refuses a name that holds another entry, naming it,
and an entry of the wrong kind) and :meth:`Registry.lookup` (an unknown name is a ``ValueError``
listing the registered ones)::

    NETWORKS = Registry("oracle network", base=nn.Module, base_text="an nn.Module subclass")

    @NETWORKS.register("mlp")
    class MLP(nn.Module): ...

    NETWORKS.lookup("cnn")  # ValueError: unknown oracle network 'cnn'; registered: ['mlp']

Plain item assignment (``reg[name] = entry``) stays a dict's: unchecked, for a caller that
replaces an entry on purpose (a test's ``monkeypatch.setitem``). This module imports nothing of
the project, so every layer (envs, modules, training) may use it.
"""

from __future__ import annotations

import reprlib
from collections.abc import Mapping
from typing import Generic, TypeVar

__all__ = ["Registry"]

T = TypeVar("T")


_SHORT = reprlib.Repr()
_SHORT.maxother = 72


def _describe(entry) -> str:
    """A short name for ``entry`` in a message: a class's or function's qualified name, else its
    repr cut to a line."""
    return getattr(entry, "__qualname__", None) or _SHORT.repr(entry)


class Registry(dict[str, T], Generic[T]):
    """``{name: entry}`` in registration order, with checked registration and lookup.

    Args:
        what: the entries' noun in messages (``"oracle network"``: ``unknown oracle network 'x'``).
        base: when given, every registered entry must be a class that subclasses it.
        base_text: the words for ``base`` in the refusal (default ``"a <Base> subclass"``).
        hint: how to add an entry, appended to the unknown-name message in parentheses
            (``"register_oracle_network in legoh_rl.modules.oracle adds one"``).
        entries: the first entries, ``{name: entry}``, each registered as by :meth:`register`.
    """

    def __init__(self, what: str, *, base: type | None = None, base_text: str | None = None, hint: str = "",
                 entries: Mapping[str, T] | None = None):
        super().__init__()
        if not isinstance(what, str) or not what:
            raise ValueError(f"a registry's noun must be a non-empty string, got {what!r}")
        self.what = what
        self.base = base
        self.base_text = base_text or (f"a {base.__qualname__} subclass" if base is not None else "")
        self.hint = hint
        for name, entry in (entries or {}).items():
            self.register(name, entry)

    def register(self, name: str, entry: T | None = None):
        """Add ``entry`` under ``name`` and return it; without ``entry``, a decorator that does so
        (``@reg.register("mlp")``). Registering the same entry under its name again is a no-op.

        Raises:
            ValueError: ``name`` is not a non-empty string, ``name`` holds another entry already
                (the message names that one), or, with ``base``, ``entry`` is not a subclass of it.
        """
        if not isinstance(name, str) or not name:
            raise ValueError(f"{self.what} name must be a non-empty string, got {name!r}")

        def add(item: T) -> T:
            if self.base is not None and not (isinstance(item, type) and issubclass(item, self.base)):
                raise ValueError(f"{self.what} {name!r} must be {self.base_text}, got {item!r}")
            if name in self and self[name] is not item:
                raise ValueError(f"{self.what} {name!r} is already registered ({_describe(self[name])})")
            self[name] = item
            return item

        return add if entry is None else add(entry)

    def lookup(self, name: str) -> T:
        """The entry registered as ``name``.

        Raises:
            ValueError: an unregistered name (the message lists the registered ones, sorted).
        """
        if not isinstance(name, str) or name not in self:
            hint = f" ({self.hint})" if self.hint else ""
            raise ValueError(f"unknown {self.what} {name!r}; registered: {sorted(self)}{hint}")
        return self[name]
