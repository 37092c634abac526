"""``monoguide plan``: the cell's layout planned from its config, the report and the drawings (docs/planning.md).
"""

from __future__ import annotations

from monoguide.daemon.plan._drawing import LAYOUT_SIZE, draw_layout
from monoguide.daemon.plan._layout import CellLayout, cell_layout, planned_pose_names, write_config_with_layout
from monoguide.daemon.plan._marks import cell_marks_check, marks_report
from monoguide.daemon.plan._report import fig5_report, print_fig5, print_layout, print_marks

__all__ = [
    "LAYOUT_SIZE", "CellLayout", "cell_layout", "cell_marks_check", "draw_layout", "fig5_report", "marks_report",
    "planned_pose_names", "print_fig5", "print_layout", "print_marks", "write_config_with_layout",
]
