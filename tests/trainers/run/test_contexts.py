"""Per-episode training contexts: the spec's syntax, its draws and their determinism."""

from __future__ import annotations

import pytest

from neuronsmae.trainers.run.contexts import ContextSpec, ContextSpecError


def test_fixed_choices_and_ranges_draw_what_they_say() -> None:
    spec = ContextSpec.parse("coef=0.5,0.7,1, 1.4;Friction_coeff=0.3..0.7; level=1 ;VK1=0.2")
    draws = [spec.sample(seed=3, k=k) for k in range(400)]
    assert {d["coef"] for d in draws} == {0.5, 0.7, 1.0, 1.4}
    assert all(0.3 <= d["Friction_coeff"] <= 0.7 for d in draws)
    assert (
        min(d["Friction_coeff"] for d in draws)
        < 0.35
        < 0.65
        < max(d["Friction_coeff"] for d in draws)
    )
    assert {d["level"] for d in draws} == {1} and {d["VK1"] for d in draws} == {0.2}
    assert not spec.fixed


def test_a_draw_depends_only_on_the_run_seed_and_the_episode() -> None:
    spec = ContextSpec.parse("coef=0.5,1,1.5,2;M=1..5")
    assert spec.sample(7, 123) == spec.sample(7, 123)  # a resumed run draws the same
    assert len({tuple(spec.sample(7, k).values()) for k in range(50)}) > 40
    assert spec.sample(7, 5) != spec.sample(8, 5)
    assert ContextSpec.parse("").sample(7, 5) == {}


def test_extremes_cover_every_choice_and_both_ends_of_every_range() -> None:
    spec = ContextSpec.parse("coef=0.5,1,2;Friction_coeff=0.1..0.9;level=hard")
    extremes = spec.extremes()
    assert [e["coef"] for e in extremes] == [0.5, 1.0, 2.0]
    assert {e["Friction_coeff"] for e in extremes} == {0.1, 0.9}
    assert {e["level"] for e in extremes} == {"hard"}


def test_fixed_specs_give_one_value_and_updates_override_keys() -> None:
    main = ContextSpec.parse("Friction_coeff=0.5;coef=1.0")
    assert main.fixed and main.value() == {"Friction_coeff": 0.5, "coef": 1.0}
    assert main.updated(ContextSpec.parse("coef=1.5")).value() == {
        "Friction_coeff": 0.5,
        "coef": 1.5,
    }
    with pytest.raises(ContextSpecError, match="must be fixed"):
        ContextSpec.parse("coef=1,2").value()


@pytest.mark.parametrize("text", ["coef", "=1", "coef=", "coef=1;coef=2", "M=3..1", "VK1=nan"])
def test_bad_specs_name_the_entry(text: str) -> None:
    with pytest.raises(ContextSpecError, match="contexts"):
        ContextSpec.parse(text)
