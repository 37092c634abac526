"""What the tests share, importable as ``helpers`` (``pythonpath = ["tests"]`` in pyproject.toml): plain modules,
never test modules, each named for what it holds. Fixtures shared by several test modules are in the
``conftest.py`` of the narrowest folder their users share."""
