"""Shipped files, not code: the simulated cell config, a real cell's commented template, the robot programs.

Read them with :mod:`monoguide.daemon.packaged` (``importlib.resources``), wherever monoguide is installed.
"""
