"""The *Calibration* page: where the cell's calibration comes from (the config's ``[calibration]`` provenance, as
``monoguide calibrate`` writes it), the wizard's report beside its session (``calibration-report.md`` and its
PNGs, shown as text and images: the PNGs addressed by their place in the folder's sorted list, never by a name
from the URL), and the previous calibration files kept beside the config; the calibration's health as the service
keeps it (``_health``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from monoguide.daemon.config import CellConfig
from monoguide.daemon.web._health import calibration_health
from monoguide.daemon.web._source import StateSource

REPORT_NAME = "calibration-report.md"
MAX_REPORT_BYTES = 2_000_000


def calibration_facts(source: StateSource) -> dict[str, Any]:
    health = calibration_health(source, source.service())
    config = source.config
    if config is None:
        return {"config": None, "provenance": None, "report": None, "figures": [], "previous": [], "health": health}
    provenance = dict(config.calibration or {})
    folder = report_folder(config)
    report = None
    if folder is not None and (folder / REPORT_NAME).is_file():
        report = (folder / REPORT_NAME).read_text(encoding="utf-8", errors="replace")[:MAX_REPORT_BYTES]
    return {"config": str(config.path), "provenance": provenance, "report": report,
            "report_path": None if folder is None else str(folder / REPORT_NAME),
            "figures": [p.name for p in report_figures(config)], "previous": _previous(config), "health": health}


def report_folder(config: CellConfig) -> Path | None:
    """The folder of the wizard's session named in ``[calibration] session`` (None when there is none)."""
    session = (config.calibration or {}).get("session")
    if not session:
        return None
    path = Path(str(session))
    if not path.is_absolute():
        path = config.path.parent / path
    return path if path.is_dir() else path.parent if path.parent.is_dir() else None


def report_figures(config: CellConfig) -> list[Path]:
    folder = report_folder(config)
    return [] if folder is None else sorted(p for p in folder.glob("*.png") if p.is_file())


def _previous(config: CellConfig) -> list[dict[str, Any]]:
    found = sorted(config.path.parent.glob(f"{config.path.stem}.*.previous.toml"), reverse=True)
    return [{"name": p.name, "bytes": p.stat().st_size} for p in found[:20]]
