"""``monoguide plant``: the plant's view of the cell — an OPC UA server shaped after OPC 40100-1 Machine Vision
and Prometheus metrics, read-only, secure by default (docs/opcua.md, docs/metrics.md).

It reads what ``monoguide status`` reads (the service's ``status.json``, the journal opened read-only) and nothing
it serves can change the cell. Modules: ``_settings`` (the plant file's ``[plant]`` and its limits),
``_metrics_access`` (``[plant.metrics_web]``: TLS, basic auth), ``_passwords``, ``_pki`` (the server's certificate),
``_access`` (trust list, users, the read-only rules), ``_logins`` (failed logins per address), ``_refusals`` (what was
refused, logged once per interval), ``_listener`` (a socket's connections counted per client), ``_wire`` (OPC UA
TCP as the relay reads it), ``_front`` (the relay on the OPC UA port), ``_sessions`` (asyncua's server and sessions
with the plant's rules), ``_states`` (the service's states as 40100's), ``_results`` and ``_result_fields`` (a
journal row as a result), ``_cell_view`` (the reader), ``_address_space``, ``_opcua``, ``_metrics``,
``_metrics_http`` (the metrics' server) and ``_serve`` (the loop).
"""

from __future__ import annotations

from monoguide.daemon.plant._passwords import hash_password, verify_password
from monoguide.daemon.plant._serve import PlantEndpoints, calibration_date, describe_cell, serve_plant
from monoguide.daemon.plant._settings import PlantSettings, PlantUser, is_loopback, load_plant_settings
from monoguide.daemon.plant._states import vision_state

__all__ = ["PlantEndpoints", "PlantSettings", "PlantUser", "calibration_date", "describe_cell", "hash_password",
           "is_loopback", "load_plant_settings", "serve_plant", "verify_password", "vision_state"]
