"""``monoguide solve``: measurement records in, part poses out (docs/measurement-record.md)."""

from __future__ import annotations

import json
import math
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Annotated, Any

import numpy as np
import typer
from rich.console import Console
from rich.table import Table

from monoguide.solver import frames
from monoguide.solver.errors import MonoguideError, RecordError
from monoguide.solver.pose import ESTIMATORS, solve_pose
from monoguide.solver.record import error_to_dict, parse_record, result_to_dict


def solve(
    records: Annotated[list[str], typer.Argument(help="Record files (.json: one object, .jsonl: one per line) or -")],
    json_output: Annotated[bool, typer.Option("--json", help="One JSON result per line (the spec's fields).")] = False,
    method: Annotated[str, typer.Option(help=f"Estimator: {', '.join(sorted(ESTIMATORS))}.")] = "ml",
    robust: Annotated[bool, typer.Option(help="Huber loss in the ML refinement (down-weights outliers).")] = False,
) -> None:
    """Solve the part pose T_s1_w of each measurement record and its offset from the reference.

    A bad record gets an error line with its code and the batch goes on; the exit status is 1 when any
    record failed.
    """
    if method not in ESTIMATORS:
        raise typer.BadParameter(f"{method!r}; choose one of {', '.join(sorted(ESTIMATORS))}", param_hint="--method")
    if robust and method != "ml":
        raise typer.BadParameter(f"the Huber loss belongs to --method ml, not {method!r}", param_hint="--robust")
    rows = [_solve_one(source, data, method, robust) for source, data in _read_records(records)]
    if json_output:
        for row in rows:
            sys.stdout.write(json.dumps(row["result"]) + "\n")
    else:
        _print_table(rows)
    if any(row["result"]["status"] != "ok" for row in rows):
        raise typer.Exit(1)


def _solve_one(source: str, data: Any, method: str, robust: bool) -> dict:
    record_id = data.get("id") if isinstance(data, dict) and isinstance(data.get("id"), str) else None
    if isinstance(data, MonoguideError):
        return {"source": source, "result": error_to_dict(None, data), "truth_error": None}
    try:
        record = parse_record(data)
        start = time.perf_counter()
        result = solve_pose(record.problem, method, robust=robust)
        elapsed_ms = (time.perf_counter() - start) * 1e3
    except MonoguideError as error:
        return {"source": source, "result": error_to_dict(record_id, error), "truth_error": None}
    truth_error = None
    if record.truth_T_s1_w is not None:
        truth_error = frames.pose_difference(result.T_s1_w, record.truth_T_s1_w)
    return {
        "source": source,
        "result": result_to_dict(record.id, result, record.problem.T_s1_w0, elapsed_ms),
        "truth_error": truth_error,
    }


def _read_records(paths: list[str]) -> Iterator[tuple[str, Any]]:
    """Yield (where, decoded object or the RecordError that stopped it) for every record."""
    for path in paths:
        try:
            text = sys.stdin.read() if path == "-" else Path(path).read_text()
        except OSError as error:
            yield path, RecordError(f"{path}: cannot read: {error.strerror or error}")
            continue
        name = "<stdin>" if path == "-" else path
        try:
            yield name, json.loads(text)
            continue
        except json.JSONDecodeError:
            pass  # not one object: one record per line
        for number, line in enumerate(text.splitlines(), start=1):
            if not line.strip():
                continue
            try:
                yield f"{name}:{number}", json.loads(line)
            except json.JSONDecodeError as error:
                message = f"{name} line {number}: not JSON ({error.msg}, column {error.colno})"
                yield f"{name}:{number}", RecordError(message)


def _print_table(rows: list[dict]) -> None:
    console = Console(width=max(Console().width, 110))
    table = Table(title="monoguide solve: part pose in SF1 and its offset from the reference")
    for column in ("record", "offset deg", "offset mm", "rms px", "σ deg", "σ mm", "vs truth", "ms"):
        table.add_column(column, justify="left" if column == "record" else "right")
    failures = []
    for row in rows:
        result = row["result"]
        label = result.get("id") or row["source"]
        if result["status"] != "ok":
            failures.append(f"[red]{label}: {result['error']['code']}[/red] {result['error']['message']}")
            continue
        offset = np.array(result["offset"])
        truth = row["truth_error"]
        table.add_row(
            label,
            f"{frames.rotation_angle_deg(offset[:3, :3]):.4f}",
            f"{math.hypot(*offset[:3, 3]):.3f}",
            f"{result['rms_px']:.3f}",
            f"{result['sigma_rot_deg']:.4f}",
            f"{result['sigma_trans_mm']:.3f}",
            "" if truth is None else f"{truth[0]:.4f}° {truth[1]:.3f} mm",
            f"{result['time_ms']:.2f}",
        )
    if table.row_count:
        console.print(table)
    for line in failures:
        console.print(line, highlight=False)
