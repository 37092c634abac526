"""The repository's own files, for a test wherever it sits in tests/."""

from __future__ import annotations

from pathlib import Path

ROOT = Path(__file__).parents[2]
CONFIG_DIR = ROOT / "config"
SIM_CELL = CONFIG_DIR / "sim-cell.toml"  # the simulated paper roof cell: the truth of every simulated device
MARKS_SIM_CELL = CONFIG_DIR / "sim-cell-marks.toml"  # the same with fixed reference marks (simulate --marks)
# the simulated cell as it was before part types (one [part], points in each pose): the single-part form, job 1
SINGLE_PART_SIM_CELL = Path(__file__).parent / "data" / "sim-cell-single-part.toml"
EXAMPLE_RECORD = ROOT / "examples" / "example-record.json"
