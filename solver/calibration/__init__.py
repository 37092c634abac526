"""Calibration of the cell's frames (paper Sec. 2.2, issue 12): camera intrinsics, the cell frame CF, the
robot base BF, the part frame WF, the measuring-pose frames SFi (Eq. 6), and the verification statistics.

Pure numerics (numpy, scipy, OpenCV), no I/O: the wizard (``monoguide calibrate``) gathers the
measurements and writes the results. See docs/calibration.md.
"""
