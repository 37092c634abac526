"""Shipped files, not code: the systemd unit of `monoguide run` and its install notes.

Read them with :mod:`monoguide.daemon.packaged`.
"""
