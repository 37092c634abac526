"""The cell config: each section's dataclass beside its reader, and the loader of the whole file
(docs/cell-config.md)."""
