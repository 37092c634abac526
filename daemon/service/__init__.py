"""The service, ``monoguide run``: the loop, the PLC link, the cycle task, the devices kept connected, the
journal, the state directory and its status file, sd_notify (docs/service.md)."""
