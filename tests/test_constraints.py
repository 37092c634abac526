"""constraints.txt pins every package pyproject.toml asks for (the dependencies, the extras test and bench, what
monoguide is built with) and pip, setuptools and wheel, each at a version within pyproject.toml's range: a
dependency added or a range narrowed without `scripts/lock.sh` fails here, not on a fresh machine
(docs/dependencies.md)."""

from __future__ import annotations

import tomllib
from pathlib import Path

from packaging.requirements import Requirement
from packaging.utils import canonicalize_name
from packaging.version import Version

ROOT = Path(__file__).resolve().parents[1]


def pins() -> dict[str, Version]:
    """constraints.txt as {canonical name: version}; every line but the comments is ``name==version``."""
    pinned: dict[str, Version] = {}
    for number, line in enumerate((ROOT / "constraints.txt").read_text().splitlines(), 1):
        if not line.strip() or line.startswith("#"):
            continue
        name, equals, version = line.partition("==")
        assert equals and name.strip() == name and version.strip() == version, f"constraints.txt:{number}: {line!r}"
        assert canonicalize_name(name) not in pinned, f"constraints.txt:{number}: {name} pinned twice"
        pinned[canonicalize_name(name)] = Version(version)
    return pinned


def asked_for() -> list[Requirement]:
    """What pyproject.toml requires: to build, to run, and with the extras test and bench."""
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())
    extras = project["project"]["optional-dependencies"]
    return [Requirement(text) for text in (*project["build-system"]["requires"], *project["project"]["dependencies"],
                                           *extras["test"], *extras["bench"])]


def test_every_package_pyproject_asks_for_is_pinned_within_its_range() -> None:
    pinned = pins()
    for requirement in asked_for():
        name = canonicalize_name(requirement.name)
        assert name in pinned, f"{requirement} has no pin in constraints.txt: run scripts/lock.sh"
        assert requirement.specifier.contains(pinned[name], prereleases=True), (
            f"constraints.txt pins {name}=={pinned[name]}, outside pyproject.toml's {requirement}: run scripts/lock.sh")


def test_the_installers_are_pinned_too() -> None:
    assert {"pip", "setuptools", "wheel"} <= set(pins())
