"""``monoguide plant``: the plant's view of the cell — an OPC UA server shaped after OPC 40100-1 Machine Vision
and Prometheus metrics, read-only, secure by default (docs/opcua.md, docs/metrics.md).

It reads what ``monoguide status`` reads (the service's ``status.json``, the journal opened read-only) and nothing
it serves can change the cell. Modules: ``_settings`` (the plant file's ``[plant]``), ``_passwords``, ``_pki``
(the server's certificate), ``_access`` (trust list, users, the read-only rules), ``_states`` (the service's states
as 40100's), ``_results`` and ``_result_fields`` (a journal row as a result), ``_cell_view`` (the reader),
``_address_space``, ``_opcua``, ``_metrics`` and ``_serve`` (the loop).
"""

from __future__ import annotations

from monoguide.daemon.plant._passwords import hash_password, verify_password
from monoguide.daemon.plant._serve import PlantEndpoints, calibration_date, describe_cell, serve_plant
from monoguide.daemon.plant._settings import PlantSettings, PlantUser, is_loopback, load_plant_settings
from monoguide.daemon.plant._states import vision_state

__all__ = ["PlantEndpoints", "PlantSettings", "PlantUser", "calibration_date", "describe_cell", "hash_password",
           "is_loopback", "load_plant_settings", "serve_plant", "verify_password", "vision_state"]
