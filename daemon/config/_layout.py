"""``[layout]``: what ``monoguide plan --layout`` plans the measuring poses for (docs/planning.md)."""

from __future__ import annotations

from dataclasses import dataclass, field

from monoguide.daemon.config._reader import ConfigTable
from monoguide.drivers.errors import ConfigError
from monoguide.solver.planning import DeviationEnvelope, LayoutConstraints


@dataclass(frozen=True)
class LayoutConfig:
    """``[layout]``: what ``monoguide plan --layout`` plans the measuring poses for (docs/planning.md)."""

    constraints: LayoutConstraints = field(default_factory=LayoutConstraints)
    envelope: DeviationEnvelope = field(default_factory=DeviationEnvelope)
    sigma_px: float = 0.1
    repeatability_mm: float = 0.05
    repeatability_deg: float = 0.01
    reach_radius_mm: float | None = None  # flange within this distance of the robot base ([reference] T_cf_b)


def read_layout(t: ConfigTable) -> LayoutConfig:
    default, envelope = LayoutConstraints(), DeviationEnvelope()
    standoff = tuple(t.vector("standoff_mm", 2, default.standoff_mm))
    depth = tuple(t.vector("depth_of_field_mm", 2, default.depth_of_field_mm))
    for key, (low, high) in (("standoff_mm", standoff), ("depth_of_field_mm", depth)):
        if not 0 < low <= high:
            raise ConfigError(f"{t.where}.{key} = {[float(low), float(high)]}: expected [min, max] with "
                              "0 < min <= max (mm)")
    angle = t.number("max_view_angle_deg", default.max_view_angle_deg, nonnegative=True)
    if angle >= 90.0:
        raise ConfigError(f"{t.where}.max_view_angle_deg = {angle}: must be below 90")
    translation = tuple(float(v) for v in t.vector("envelope_translation_mm", 3, envelope.translation_mm))
    rotation = tuple(float(v) for v in t.vector("envelope_rotation_deg", 3, envelope.rotation_deg))
    if min(translation) < 0 or min(rotation) < 0 or max(rotation) >= 45.0:
        raise ConfigError(f"{t.where}: envelope_translation_mm = {list(translation)}, envelope_rotation_deg = "
                          f"{list(rotation)}: expected +- ranges >= 0 (rotations below 45)")
    centre = t.vector("envelope_centre_w", 3, None)
    out = LayoutConfig(
        constraints=LayoutConstraints(
            standoff_mm=(float(standoff[0]), float(standoff[1])),
            max_view_angle_deg=angle,
            margin_px=t.number("margin_px", default.margin_px, nonnegative=True),
            depth_of_field_mm=(float(depth[0]), float(depth[1])),
            max_view_angle_envelope_deg=t.number("max_view_angle_envelope_deg", None, positive=True),
        ),
        envelope=DeviationEnvelope(translation, rotation, None if centre is None else tuple(float(v) for v in centre)),
        sigma_px=t.number("sigma_px", 0.1, positive=True),
        repeatability_mm=t.number("repeatability_mm", 0.05, nonnegative=True),
        repeatability_deg=t.number("repeatability_deg", 0.01, nonnegative=True),
        reach_radius_mm=t.number("reach_radius_mm", None, positive=True),
    )
    t.done()
    return out
