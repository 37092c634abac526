"""One measuring cycle: the state machine of its states and the blocking work of each (docs/cycle.md)."""
