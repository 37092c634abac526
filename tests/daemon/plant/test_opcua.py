"""The OPC UA server with the real asyncua client: the VisionSystem browsed, its results and recipes read against the
seeded journal, a result event per newly committed cycle, and every way in that must be refused."""

from __future__ import annotations

import asyncio
import hashlib
import subprocess
import sys
import time
import tomllib
from pathlib import Path

import pytest
from asyncua import ua
from asyncua.ua.uaerrors import UaError
from helpers.plant_cells import PASSWORD, USER, PlantCell, StatusBeat, plant_file, seeded_entries
from helpers.plant_clients import (
    NAMESPACE,
    client_identity,
    connected,
    load_machine_vision_types,
    start_plant,
    subscribe_results,
    trust,
    value,
)
from helpers.repository import SIM_CELL
from helpers.sim_processes import stop

from monoguide.daemon.service import Journal

HOST, PORT = "127.0.81.1", 48101


def _jobs() -> dict[int, str]:
    """Job number -> part name, from the config file's text: its [[parts]], else its one [part] as job 1."""
    raw = tomllib.loads(SIM_CELL.read_text())
    if "parts" in raw:
        return {int(p["job"]): p["name"] for p in raw["parts"]}
    return {1: raw["part"].get("name", "part")}


def _node(client: object, idx: int, path: str) -> object:
    return client.get_node(ua.NodeId(path, idx))  # type: ignore[attr-defined]


async def _read(client: object, idx: int, path: str) -> object:
    return await _node(client, idx, path).read_value()  # type: ignore[attr-defined]


def test_the_vision_system_shows_the_journal(plant_cell: PlantCell) -> None:
    async def run() -> None:
        client = await connected(plant_cell.url, plant_cell.client, user=USER, password=PASSWORD)
        try:
            idx = await client.get_namespace_index(NAMESPACE)
            mv = await load_machine_vision_types(client)
            objects = [(await n.read_browse_name()).Name for n in await client.nodes.objects.get_children()]
            assert "VisionSystem" in objects
            vs = _node(client, idx, "VisionSystem")
            children = {(await n.read_browse_name()).to_string() for n in await vs.get_children()}  # type: ignore[attr-defined]
            assert {f"{mv}:VisionStateMachine", f"{mv}:RecipeManagement", f"{mv}:ResultManagement",
                    f"{idx}:Devices", f"{idx}:CalibrationHealth"} <= children
            type_node = await vs.read_type_definition()  # type: ignore[attr-defined]
            assert type_node == ua.NodeId(1003, mv)  # the published VisionSystemType
            # the status file says idle: Operational / Ready
            machine = _node(client, idx, "VisionSystem.VisionStateMachine")
            current = await machine.get_child("0:CurrentState")  # type: ignore[attr-defined]
            assert (await current.read_value()).Text == "Operational"
            automatic = await (await machine.get_child(f"{mv}:AutomaticModeStateMachine")).get_child(  # type: ignore[attr-defined]
                "0:CurrentState")
            assert (await automatic.read_value()).Text == "Ready"
            # recipes: the config's part types by job number (its one [part] as job 1)
            for job, name in _jobs().items():
                assert await _read(client, idx, f"VisionSystem.RecipeManagement.Recipes.Job{job}.JobNumber") == job
                assert await _read(client, idx, f"VisionSystem.RecipeManagement.Recipes.Job{job}.PartName") == name
            # the newest results, Result01 the newest, against the seeded rows
            newest = len(plant_cell.seeded)
            for slot in range(1, 11):
                number = newest - slot + 1
                entry = plant_cell.seeded[number - 1]
                base = f"VisionSystem.ResultManagement.Results.Result{slot:02d}"
                assert (await _read(client, idx, f"{base}.ResultId")).Id == str(number)  # type: ignore[attr-defined]
                assert await _read(client, idx, f"{base}.PartTag") == entry.part_tag
                offset_node = _node(client, idx, f"{base}.BaseOffset")
                assert await offset_node.read_value_rank() == 1  # type: ignore[attr-defined]
                dv = await offset_node.read_data_value(raise_on_bad_status=False)  # type: ignore[attr-defined]
                if entry.error is None:
                    assert dv.Value.Value == pytest.approx(entry.result["base_offset_xyzabc"], abs=1e-9)
                    assert await _read(client, idx, f"{base}.ErrorCode") == ""
                else:
                    assert dv.StatusCode.value == ua.StatusCodes.BadNoDataAvailable
                    assert await _read(client, idx, f"{base}.ErrorCode") == entry.error.code
                    assert await _read(client, idx, f"{base}.PlcCode") == entry.error.plc_code
                assert await _read(client, idx, f"{base}.CycleTime") == pytest.approx(entry.timings_s["cycle"])
            # devices as status.json names them; no calibration health in this status file: no data
            assert await _read(client, idx, "VisionSystem.Devices.camera.Connected") is True
            assert await _read(client, idx, "VisionSystem.Devices.robot.LastErrorCode") == "DEVICE_DISCONNECTED"
            health = await _node(client, idx, "VisionSystem.CalibrationHealth.HealthLevel").read_data_value(  # type: ignore[attr-defined]
                raise_on_bad_status=False)
            assert health.StatusCode.value == ua.StatusCodes.BadNoDataAvailable
        finally:
            await client.disconnect()

    asyncio.run(run())


def test_a_result_event_per_committed_cycle(plant_cell: PlantCell) -> None:
    """Cycles committed by the real Journal while a client is subscribed: one event each, with the row's values."""
    async def run() -> None:
        client = await connected(plant_cell.url, plant_cell.client, user=USER, password=PASSWORD)
        try:
            await load_machine_vision_types(client)
            log, _ = await subscribe_results(client)
            await asyncio.sleep(0.5)
            new = seeded_entries(8, time.time())[4:8]  # one failed (index 7), three good
            with Journal(plant_cell.state_dir) as journal:
                numbers = []
                for entry in new:
                    numbers.append(journal.commit_cycle(entry))
                    await asyncio.sleep(0.05)
            await log.wait_for(len(new), 10.0)
            assert [value(e, "ResultId").Id for _, e in log.events] == [str(n) for n in numbers]
            assert [value(e, "JobId").Id for _, e in log.events] == [str(n) for n in numbers]
            for (arrived, fields), entry in zip(log.events, new, strict=True):
                assert value(fields, "PartTag") == entry.part_tag
                assert value(fields, "Job") == 1
                if entry.error is None:
                    assert value(fields, "Status") == "ok" and value(fields, "ResultState") == 1
                    assert value(fields, "ResultContent")[0].Value == pytest.approx(entry.result["base_offset_xyzabc"])
                    assert value(fields, "BaseOffset") == pytest.approx(entry.result["base_offset_xyzabc"], rel=1e-7)
                    assert value(fields, "RmsPx") == pytest.approx(entry.result["rms_px"])
                else:
                    assert value(fields, "ErrorCode") == entry.error.code
                    assert value(fields, "PlcCode") == entry.error.plc_code
                    assert value(fields, "BaseOffset") is None
                assert arrived - entry.finished_at < 2.0
        finally:
            await client.disconnect()

    asyncio.run(run())


def test_the_none_policy_is_not_offered(plant_cell: PlantCell) -> None:
    async def run() -> None:
        from asyncua import Client

        client = Client(plant_cell.url, timeout=5)
        endpoints = await client.connect_and_get_server_endpoints()
        assert {(e.SecurityPolicyUri.rsplit("#", 1)[1], e.SecurityMode) for e in endpoints} == {
            ("Basic256Sha256", ua.MessageSecurityMode.SignAndEncrypt),
            ("Aes256_Sha256_RsaPss", ua.MessageSecurityMode.SignAndEncrypt)}
        tokens = {t.TokenType for e in endpoints for t in e.UserIdentityTokens}
        assert ua.UserTokenType.Anonymous not in tokens
        with pytest.raises((UaError, OSError, TimeoutError)):
            await connected(plant_cell.url, None, user=USER, password=PASSWORD, timeout_s=5)  # no security at all
        with pytest.raises((UaError, OSError, TimeoutError)):  # signed only, not encrypted
            await connected(plant_cell.url, plant_cell.client, user=USER, password=PASSWORD,
                            mode=ua.MessageSecurityMode.Sign, timeout_s=5)

    asyncio.run(run())


@pytest.mark.parametrize(("who", "user", "password", "refusal"), [
    ("anonymous", None, None, "BadIdentityTokenRejected"),
    ("wrong password", USER, "wrong", "BadUserAccessDenied"),
    ("unknown user", "intruder", PASSWORD, "BadUserAccessDenied"),
    ("untrusted certificate", USER, PASSWORD, "BadCertificateUntrusted"),
])
def test_refused(plant_cell: PlantCell, who: str, user: str | None, password: str | None, refusal: str) -> None:
    identity = plant_cell.stranger if who == "untrusted certificate" else plant_cell.client

    async def run() -> None:
        with pytest.raises(UaError) as refused:
            client = await connected(plant_cell.url, identity, user=user, password=password, timeout_s=5)
            await client.disconnect()
        assert type(refused.value).__name__ == refusal, refused.value

    asyncio.run(run())


def test_an_x509_identity_from_the_trust_list_is_let_in(plant_cell: PlantCell) -> None:
    async def run() -> None:
        client = await connected(plant_cell.url, plant_cell.client, x509_identity=True)
        try:
            idx = await client.get_namespace_index(NAMESPACE)
            assert await _read(client, idx, "VisionSystem.Service.CycleCounter") >= 1
        finally:
            await client.disconnect()

    asyncio.run(run())


def test_nothing_can_be_written_or_called(plant_cell: PlantCell) -> None:
    async def run() -> None:
        client = await connected(plant_cell.url, plant_cell.client, user=USER, password=PASSWORD)
        try:
            idx = await client.get_namespace_index(NAMESPACE)
            node = _node(client, idx, "VisionSystem.RecipeManagement.Recipes.Job1.PartName")
            with pytest.raises(UaError) as refused:
                await node.write_value(ua.DataValue(ua.Variant("other", ua.VariantType.String)))  # type: ignore[attr-defined]
            assert type(refused.value).__name__ == "BadUserAccessDenied"
            assert await node.read_value() == _jobs()[1]  # type: ignore[attr-defined]
            server = client.nodes.server
            with pytest.raises(UaError) as refused:  # a method of the standard Server object
                await server.call_method("0:GetMonitoredItems", ua.Variant(1, ua.VariantType.UInt32))
            assert type(refused.value).__name__ == "BadUserAccessDenied"
            with pytest.raises(UaError) as refused:
                await client.nodes.objects.add_object(idx, "Intruder")
            assert type(refused.value).__name__ == "BadUserAccessDenied"
            with pytest.raises(UaError):
                await _node(client, idx, "VisionSystem").delete()  # type: ignore[attr-defined]
            assert [(await n.read_browse_name()).Name for n in await client.nodes.objects.get_children()].count(
                "Intruder") == 0
        finally:
            await client.disconnect()

    asyncio.run(run())


def test_the_server_key_is_private_and_its_thumbprint_said(plant_cell: PlantCell) -> None:
    pki = plant_cell.state_dir / "plant"
    assert (pki / "server-key.pem").stat().st_mode & 0o777 == 0o600
    assert pki.stat().st_mode & 0o777 == 0o700
    sha1 = hashlib.sha1((pki / "server-certificate.der").read_bytes()).hexdigest().upper()
    assert plant_cell.line.endswith(":".join(sha1[i:i + 2] for i in range(0, 40, 2)))


def test_anonymous_only_on_loopback(tmp_path: Path) -> None:
    """anonymous = true with a plant-network address is a config error (exit 2, nothing served)."""
    plant_toml = plant_file(tmp_path / "plant.toml", "0.0.0.0", 48111, "anonymous = true")
    done = subprocess.run([sys.executable, "-m", "monoguide.daemon.cli", "plant", "--config", str(SIM_CELL),
                           "--state-dir", str(tmp_path / "state"), "--plant-config", str(plant_toml)],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 2, done.stderr
    assert "anonymous = true with opcua_host = '0.0.0.0'" in done.stderr
    assert "CONFIG_INVALID" in done.stderr or "CONFIG" in done.stderr.split()[4]


def test_anonymous_on_loopback_when_configured(tmp_path: Path) -> None:
    host, port = "127.0.81.2", 48121
    state_dir = tmp_path / "state"
    state_dir.mkdir()
    beat = StatusBeat(state_dir)
    client_id = client_identity(tmp_path / "clients", "local-hmi")
    trust(client_id, state_dir / "plant" / "trusted")
    process, line = start_plant(SIM_CELL, state_dir, plant_file(tmp_path / "plant.toml", host, port,
                                                                  "anonymous = true"), tmp_path / "plant.log")
    try:
        async def run() -> None:
            client = await connected(line.split()[2], client_id)  # anonymous, over a trusted encrypted channel
            try:
                idx = await client.get_namespace_index(NAMESPACE)
                assert await _read(client, idx, "VisionSystem.Service.State") == "idle"
            finally:
                await client.disconnect()
            stranger = client_identity(tmp_path / "clients", "stranger")
            with pytest.raises(UaError) as refused:  # anonymous still needs a trusted certificate
                await connected(line.split()[2], stranger, timeout_s=5)
            assert type(refused.value).__name__ == "BadCertificateUntrusted"

        asyncio.run(run())
    finally:
        stop(process)
        beat.stop()


def test_no_client_can_register_a_server(plant_cell: PlantCell) -> None:
    """RegisterServer is answered before any session: refused to a client the trust list does not know, and the
    servers FindServers tells of stay this one."""
    async def run() -> None:
        from asyncua import Client
        from helpers.plant_clients import POLICIES

        client = Client(plant_cell.url, timeout=5)
        client.application_uri = plant_cell.stranger.application_uri
        await client.set_security(POLICIES["Basic256Sha256"], str(plant_cell.stranger.certificate),
                                  str(plant_cell.stranger.key), mode=ua.MessageSecurityMode.SignAndEncrypt)
        await client.connect_socket()
        try:
            await client.send_hello()
            await client.open_secure_channel()
            server = ua.RegisteredServer()
            server.ServerUri, server.ProductUri = "urn:intruder", "urn:intruder"
            server.ServerNames = [ua.LocalizedText("intruder")]
            server.DiscoveryUrls = ["opc.tcp://127.0.81.99:4840"]
            server.IsOnline = True
            with pytest.raises(UaError) as refused:
                await client.uaclient.register_server(server)
            assert type(refused.value).__name__ == "BadServiceUnsupported"
            found = await client.find_servers()
            assert [s.ApplicationUri for s in found] == [found[0].ApplicationUri]
            assert "intruder" not in found[0].ApplicationUri
        finally:
            await client.close_secure_channel()
            client.disconnect_socket()

    asyncio.run(run())


@pytest.mark.parametrize(("probe", "who", "refusal"), [
    ("results", "client", None),
    ("wrong-password", "client", "BadUserAccessDenied"),
    ("results", "stranger", "BadCertificateUntrusted"),
])
def test_a_second_stack_binds_reads_and_is_refused_alike(plant_cell: PlantCell, probe: str, who: str,
                                                         refusal: str | None) -> None:
    """node-opcua's client (not asyncua): by the published browse names it reads the state's StateNumber and
    Result01's JobId and fetches that result with GetResultById; refused as asyncua's client is."""
    from helpers.plant_wire import node_probe

    identity = plant_cell.client if who == "client" else plant_cell.stranger
    answer = node_probe(probe, plant_cell.url, identity, USER, PASSWORD)
    assert answer.refused == refusal, answer
    if refusal is None:
        with Journal(plant_cell.state_dir, read_only=True) as journal:
            newest = str(journal.cycle_counter())
        assert answer.value == {"stateNumber": 4, "jobId": newest, "callStatus": "Good", "resultId": newest,
                                "jobOfResult": newest, "error": 0}  # 4: Operational's StateNumber as published
