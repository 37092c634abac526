"""``python -m monoguide.daemon.cli``: the same as the ``monoguide`` command."""

from monoguide.daemon.cli import main

if __name__ == "__main__":
    main()
