"""Every error class of monoguide has a stable, unique ``code`` and a unique ``plc_code`` (issue 7, item 10).

The PLC's error register and the journal tell failures apart by these alone, so two classes sharing one
would make two different failures look the same on the line. Every module is imported first, so that
classes defined anywhere (solver, drivers, the simulated devices, daemon) are seen.
"""

from __future__ import annotations

import importlib
import pkgutil
import re
from collections import defaultdict

import pytest

from monoguide.solver.errors import MonoguideError, all_error_classes

PACKAGES = ("monoguide.solver", "monoguide.drivers", "monoguide.daemon")
CODE = re.compile(r"^[A-Z][A-Z0-9]*(_[A-Z0-9]+)*$")


def _import_everything() -> list[str]:
    names = []
    for package_name in PACKAGES:
        package = importlib.import_module(package_name)
        names.append(package_name)
        for info in pkgutil.walk_packages(package.__path__, prefix=f"{package_name}."):
            importlib.import_module(info.name)
            names.append(info.name)
    return names


MODULES = _import_everything()
CLASSES = all_error_classes()


def _where(cls: type) -> str:
    return f"{cls.__module__}.{cls.__qualname__}"


def test_every_module_was_imported() -> None:
    assert {"monoguide.solver.errors", "monoguide.drivers.errors", "monoguide.daemon.cli"} <= set(MODULES)
    assert any(name.startswith("monoguide.drivers.sim.") for name in MODULES)
    assert len(CLASSES) > 20


@pytest.mark.parametrize("cls", CLASSES, ids=_where)
def test_each_class_declares_its_own_code_and_plc_code(cls: type[MonoguideError]) -> None:
    assert isinstance(cls.code, str) and CODE.match(cls.code), f"{_where(cls)}: code {cls.code!r} not UPPER_SNAKE"
    assert isinstance(cls.plc_code, int) and not isinstance(cls.plc_code, bool), f"{_where(cls)}: plc_code"
    assert 1 <= cls.plc_code <= 999, f"{_where(cls)}: plc_code {cls.plc_code} outside 1..999 (0 means no error)"
    if cls is not MonoguideError:  # an inherited code would make the subclass indistinguishable
        assert "code" in vars(cls) and "plc_code" in vars(cls), f"{_where(cls)} inherits its code"


@pytest.mark.parametrize("attribute", ["code", "plc_code"])
def test_codes_are_unique(attribute: str) -> None:
    owners: dict[object, list[str]] = defaultdict(list)
    for cls in CLASSES:
        owners[getattr(cls, attribute)].append(_where(cls))
    shared = {value: names for value, names in owners.items() if len(names) > 1}
    assert not shared, f"{attribute} shared: {shared}"
