"""``monoguide plan``: the cell's layout planned from its config, the report and the drawings (docs/planning.md)."""
