"""Config, cycle state machine, PLC handshake, journal, service main, CLI and calibration wizard."""
