"""legoh_rl.registry.Registry, the one name -> entry table of the networks, terrain primitives and
reward terms: hand-made cases of registering (call and decorator), refusals and lookup."""

from __future__ import annotations

import pytest

from legoh_rl.envs.rewards import REWARD_TERMS
from legoh_rl.envs.trails.primitives import PRIMITIVES
from legoh_rl.modules.locomotion import LOCOMOTION_NETWORKS
from legoh_rl.modules.oracle import ORACLE_NETWORKS
from legoh_rl.modules.perception import PERCEPTION_BUILDERS
from legoh_rl.registry import Registry


class Base:
    """The registry's base class in these tests."""


class Small(Base):
    """An entry."""


class Large(Base):
    """Another entry."""


def shapes() -> Registry[type[Base]]:
    return Registry("shape", base=Base, hint="shapes.register adds one")


def test_register_by_call_and_as_decorator_returns_the_entry():
    reg = shapes()
    assert reg.register("small", Small) is Small

    @reg.register("large")
    class Decorated(Large):
        """Registered by the decorator form."""

    assert reg == {"small": Small, "large": Decorated} and list(reg) == ["small", "large"]
    assert reg.lookup("large") is Decorated and reg["small"] is Small
    assert reg.register("small", Small) is Small  # the same entry again: a no-op
    assert isinstance(reg, dict) and len(reg) == 2


def test_a_taken_name_is_refused_naming_the_class_it_holds():
    reg = shapes()
    reg.register("small", Small)
    with pytest.raises(ValueError, match=r"^shape 'small' is already registered \(Small\)$"):
        reg.register("small", Large)
    with pytest.raises(ValueError, match=r"shape 'small' is already registered \(Small\)"):
        reg.register("small")(Large)
    assert reg["small"] is Small


def test_an_entry_that_is_not_a_subclass_of_base_is_refused():
    reg = shapes()
    for bad in (object, Small(), "small", None.__class__):
        with pytest.raises(ValueError, match=r"shape 'x' must be a Base subclass, got "):
            reg.register("x", bad)
    worded = Registry("network", base=Base, base_text="an nn.Module subclass")
    with pytest.raises(ValueError, match=r"^network 'x' must be an nn.Module subclass, got <class 'int'>$"):
        worded.register("x", int)
    assert not reg and not worded


@pytest.mark.parametrize("name", ["", None, 3, ("a",)])
def test_a_name_that_is_not_a_non_empty_string_is_refused(name):
    with pytest.raises(ValueError, match=r"shape name must be a non-empty string, got "):
        shapes().register(name, Small)


def test_an_unknown_name_lists_the_registered_ones_and_the_hint():
    reg = shapes()
    reg.register("small", Small)
    reg.register("large", Large)
    with pytest.raises(ValueError, match=r"^unknown shape 'huge'; registered: \['large', 'small'\] "
                                         r"\(shapes.register adds one\)$"):
        reg.lookup("huge")
    with pytest.raises(ValueError, match=r"^unknown shape \['small'\]; registered: "):
        reg.lookup(["small"])  # not hashable: still the same refusal
    with pytest.raises(ValueError, match=r"^unknown thing 'a'; registered: \[\]$"):
        Registry("thing").lookup("a")


def test_any_entry_without_base_and_first_entries_registered_in_order():
    # module-level functions of this file, not builtins: another test's library (Ray) may replace
    # builtins.print for the rest of the session
    reg = Registry("builder", entries={"b": shapes, "a": test_a_plain_assignment_stays_a_dicts})
    assert list(reg) == ["b", "a"] and reg.lookup("a") is test_a_plain_assignment_stays_a_dicts
    taken = r"builder 'a' is already registered \(test_a_plain_assignment_stays_a_dicts\)"
    with pytest.raises(ValueError, match=taken):
        reg.register("a", shapes)
    with pytest.raises(ValueError, match=taken):
        Registry("builder", entries={"a": test_a_plain_assignment_stays_a_dicts}).register("a", 3)
    with pytest.raises(ValueError, match=r"a registry's noun must be a non-empty string, got ''"):
        Registry("")


def test_a_plain_assignment_stays_a_dicts():
    """Item assignment is unchecked on purpose (a test's ``monkeypatch.setitem`` replaces an entry)."""
    reg = shapes()
    reg["small"] = Small
    reg["small"] = Large
    assert reg.lookup("small") is Large
    assert reg.pop("small") is Large and not reg


def test_the_projects_tables_are_registries():
    for table, what in ((ORACLE_NETWORKS, "oracle network"), (LOCOMOTION_NETWORKS, "locomotion network"),
                        (PERCEPTION_BUILDERS, "perception network"), (PRIMITIVES, "terrain primitive"),
                        (REWARD_TERMS, "reward term")):
        assert isinstance(table, Registry) and table.what == what and table
        name = next(iter(table))
        assert table.lookup(name) is table[name]
        with pytest.raises(ValueError, match=rf"^unknown {what} 'nope'; registered: \[.*{name!r}"):
            table.lookup("nope")
