"""The option and context tables in docs/ list every option and key the code accepts."""

from __future__ import annotations

import dataclasses
from pathlib import Path

from neuronsmae.server.config import ArenaConfig
from neuronsmae.server.contexts import CONTEXT_TABLE

DOCS = Path(__file__).resolve().parents[2] / "docs"


def test_every_option_is_documented() -> None:
    text = (DOCS / "options.md").read_text()
    for f in dataclasses.fields(ArenaConfig):
        assert f"`{f.name}`" in text, f.name


def test_every_context_key_is_documented() -> None:
    text = (DOCS / "contexts.md").read_text()
    for key in [*CONTEXT_TABLE, "level"]:
        assert f"`{key}`" in text, key


def test_every_level_value_has_a_row_in_the_bots_table() -> None:
    from neuronsmae.protocol.levels import LEVEL_CHOICES

    text = (DOCS / "contexts.md").read_text()
    bots = text[text.index("## Bots") :]
    for level in LEVEL_CHOICES:
        assert f"\n| `{level}`" in bots, level
