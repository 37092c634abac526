"""``monoguide calibrate``: the wizard's rig, session and steps, the calibration file and the report
(docs/calibration.md)."""
