"""config/cell-template.toml: it loads with the real loader, and it holds (and comments) every key the loader asks
for. The key list is the loader's own: every :class:`ConfigTable` the loader creates records which keys its getters
asked for, so a key someone adds to a section reader in ``daemon/config/`` without adding it to the template fails
here."""

from __future__ import annotations

import re
import tomllib
from pathlib import Path
from typing import Any

import pytest

from monoguide.daemon.config import OPTIONAL_SECTIONS, PARTS_SECTIONS, REQUIRED_SECTIONS, load_cell_config
from monoguide.daemon.config import _reader as config_reader

TEMPLATE = Path(__file__).parents[3] / "config" / "cell-template.toml"
NOT_IN_TEMPLATE = {"sim"}  # the simulated cell's own section (config/sim-cell.toml)


def _asked_keys(monkeypatch: pytest.MonkeyPatch) -> tuple[Any, list[config_reader.ConfigTable]]:
    """Load the template, keeping every table the loader read (their ``known``: the keys it asked for)."""
    tables: list[config_reader.ConfigTable] = []
    init = config_reader.ConfigTable.__init__

    def recording(self: config_reader.ConfigTable, *args: Any, **kwargs: Any) -> None:
        init(self, *args, **kwargs)
        tables.append(self)

    monkeypatch.setattr(config_reader.ConfigTable, "__init__", recording)
    return load_cell_config(TEMPLATE), tables


def _entries(raw: dict[str, Any], name: str) -> list[dict[str, Any]]:
    """The template's table(s) at dotted ``name`` (an array of tables gives each entry)."""
    nodes: list[Any] = [raw]
    for part in name.split(".") if name else []:
        nodes = [n[part] for n in nodes if part in n]
        nodes = [entry for n in nodes for entry in (n if isinstance(n, list) else [n])]
    return nodes


def test_the_template_loads_and_holds_every_key_the_loader_asks_for(monkeypatch: pytest.MonkeyPatch) -> None:
    config, tables = _asked_keys(monkeypatch)
    assert config.camera.backend == "genicam" and config.robot is not None and not config.robot.simulated
    assert config.tracker is not None and config.tracker.backend == "serial" and config.sim is None
    raw = tomllib.loads(TEMPLATE.read_text())
    sections = set(REQUIRED_SECTIONS) | set(OPTIONAL_SECTIONS)
    assert sections - NOT_IN_TEMPLATE <= set(raw), f"sections missing: {sections - NOT_IN_TEMPLATE - set(raw)}"
    missing = []
    for table in tables:
        if table.name.split(".")[0] in NOT_IN_TEMPLATE:
            continue
        present = set().union(*(entry.keys() for entry in _entries(raw, table.name)))
        asked = table.known - (sections | set(PARTS_SECTIONS) if not table.name else set())  # [[parts]]: the other form
        missing += [f"[{table.name}] {key}" for key in sorted(asked - present)]
    assert tables and not missing, f"keys the loader reads that config/cell-template.toml lacks: {missing}"


def test_every_key_of_the_template_is_commented() -> None:
    lines = TEMPLATE.read_text().splitlines()
    uncommented = [line for i, line in enumerate(lines)
                   if re.match(r"^[A-Za-z_][A-Za-z0-9_]* = ", line) and "#" not in line
                   and not lines[i - 1].lstrip().startswith("#")]
    assert not uncommented, f"keys without a comment (on the line, or the one above): {uncommented}"
