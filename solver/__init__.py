"""Pure math of monoguide: frames, camera model, hole centres, pose, uncertainty, planning, base offset.

No I/O and no clocks live here; see ``docs/design.md``.
"""
