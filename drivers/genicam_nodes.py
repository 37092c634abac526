"""The meaning of a GenICam camera's features: setting nodes within their limits, and typed errors.

Every call into ``genicam`` / ``harvesters`` runs inside :func:`device_errors`, which turns whatever they
raise (``genicam.genapi`` and ``genicam.gentl`` exceptions, and the ``AttributeError`` / ``OSError`` a dead
device handle gives) into a :class:`~monoguide.solver.errors.MonoguideError` subclass naming the camera,
the node and the value. Settings are checked against the node's own limits before they are written:
an integer node's ``min``, ``max`` and ``inc`` (a width of 641 on a camera that steps by 4 is refused with
the two nearest valid values, never rounded), a float node's ``min`` and ``max`` (the camera may round a
float to its own resolution; the value it took is logged).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

from genicam import genapi, gentl

from monoguide.drivers.errors import (
    DeviceBusy,
    DeviceDisconnected,
    DeviceError,
    DeviceProtocolError,
    DeviceSettingRejected,
    DeviceTimeout,
)
from monoguide.solver.errors import MonoguideError

log = logging.getLogger(__name__)

TRIGGER_NODES = ("TriggerSelector", "TriggerMode", "TriggerSource", "TriggerSoftware")


@contextmanager
def device_errors(device: str, action: str) -> Iterator[None]:
    """Run a block of camera calls; anything it raises leaves as a :class:`MonoguideError` whose message is
    ``"<device>: <action>: <what the library said>"``. ``action`` names the node and the value."""
    try:
        yield
    except MonoguideError:
        raise
    except (genapi.OutOfRangeException, genapi.InvalidArgumentException) as exc:
        raise DeviceSettingRejected(f"{device}: {action}: refused: {_said(exc)}") from exc
    except genapi.AccessException as exc:
        raise DeviceSettingRejected(f"{device}: {action}: not accessible now (read-only, locked while "
                                    f"acquiring, or not available): {_said(exc)}") from exc
    except (genapi.TimeoutException, gentl.TimeoutException) as exc:
        raise DeviceTimeout(f"{device}: {action}: timed out: {_said(exc)}") from exc
    except (gentl.ResourceInUseException, gentl.BusyException, gentl.AccessDeniedException) as exc:
        raise DeviceBusy(f"{device}: {action}: in use by another client: {_said(exc)}") from exc
    except genapi.GenericException as exc:  # LogicalError, Runtime, DynamicCast, Property
        raise DeviceProtocolError(f"{device}: {action}: the camera's feature description answered "
                                  f"inconsistently ({type(exc).__name__}): {_said(exc)}") from exc
    except (gentl.GenericException, AttributeError, OSError) as exc:
        # the producer or the device is gone (cable pulled, device reset): the handle is unusable
        raise DeviceDisconnected(f"{device}: {action}: failed: {type(exc).__name__}: {_said(exc)}") from exc
    except Exception as exc:
        log.exception("%s: %s: unexpected failure", device, action)
        raise DeviceError(f"{device}: {action}: unexpected {type(exc).__name__}: {exc}") from exc


def set_enum(nodes: Any, device: str, name: str, value: str, required: bool) -> bool:
    """Set enumeration ``name`` to ``value``; ``False`` (logged) if the camera lacks an optional node."""
    if not nodes.has_node(name):
        return lacking(device, name, value, required)
    with device_errors(device, f"{name} = {value!r}"):
        node = nodes.get_node(name)
        offered = list(node.symbolics)
        if value not in offered:
            raise DeviceSettingRejected(f"{device}: {name} = {value!r} not supported; it offers {offered}")
        node.value = value
    return True


def set_number(nodes: Any, device: str, name: str, value: float, required: bool) -> bool:
    """Set integer or float node ``name`` to ``value`` after checking its limits (see the module text);
    ``False`` (logged) if the camera lacks an optional node."""
    if not nodes.has_node(name):
        return lacking(device, name, value, required)
    with device_errors(device, f"{name} = {value!r}"):
        node = nodes.get_node(name)
        current = node.value
        if isinstance(current, int) and not isinstance(current, bool):
            node.value = _checked_integer(node, device, name, value)
        else:
            node.value = _checked_float(node, device, name, value)
            if node.value != value:
                log.info("%s: %s = %r taken as %r (the camera's resolution)", device, name, value, node.value)
    return True


def lacking(device: str, name: str, value: object, required: bool) -> bool:
    """A feature the camera does not have: an error when the cell needs it, else logged and skipped."""
    if required:
        raise DeviceSettingRejected(f"{device}: has no {name} feature (wanted {value!r})")
    log.info("%s: no %s feature, %r not set", device, name, value)
    return False


def enable_software_trigger(nodes: Any, device: str) -> bool:
    """Switch the frame-start trigger to software; ``False`` when the camera has no software trigger
    (it then runs free)."""
    if not all(nodes.has_node(n) for n in TRIGGER_NODES):
        log.info("%s: no software trigger; free-running", device)
        return False
    with device_errors(device, "TriggerSelector = 'FrameStart'"):
        if "FrameStart" in nodes.TriggerSelector.symbolics:
            nodes.TriggerSelector.value = "FrameStart"
    set_enum(nodes, device, "TriggerMode", "On", required=True)
    set_enum(nodes, device, "TriggerSource", "Software", required=True)
    return True


# --- private -----------------------------------------------------------------------------------


def _checked_integer(node: Any, device: str, name: str, value: float) -> int:
    if isinstance(value, bool) or not isinstance(value, int | float) or not float(value).is_integer():
        raise DeviceSettingRejected(f"{device}: {name} = {value!r}: the node takes whole numbers")
    wanted = int(value)
    lo, hi = int(node.min), int(node.max)
    inc = _increment(node)
    if not lo <= wanted <= hi:
        raise DeviceSettingRejected(f"{device}: {name} = {wanted} outside [{lo}, {hi}]")
    if (wanted - lo) % inc:
        below = wanted - (wanted - lo) % inc
        valid = [v for v in (below, below + inc) if lo <= v <= hi]
        raise DeviceSettingRejected(f"{device}: {name} = {wanted}: the camera steps by {inc} from {lo}; "
                                    f"nearest valid: {' or '.join(map(str, valid))}")
    return wanted


def _checked_float(node: Any, device: str, name: str, value: float) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise DeviceSettingRejected(f"{device}: {name} = {value!r}: not a finite number")
    lo, hi = float(node.min), float(node.max)
    if not lo <= value <= hi:
        raise DeviceSettingRejected(f"{device}: {name} = {value} outside [{lo}, {hi}]")
    return float(value)


def _increment(node: Any) -> int:
    try:
        inc = int(node.inc)
    except (genapi.GenericException, AttributeError):  # a node without an increment steps by 1
        return 1
    return max(inc, 1)


def _said(exc: BaseException) -> str:
    """The library's message without its C++ source location."""
    text = str(exc) or type(exc).__name__
    return text.split(" (file '")[0].strip()
