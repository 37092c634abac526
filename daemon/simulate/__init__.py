"""``monoguide simulate``: the run's configs, the run itself, its summary and its report (docs/simulate.md)."""
