"""Config bounds: every duration and count has its documented range, names are non-empty and unique, hosts are
addresses or host names, the measuring poses give the pose solver its redundancy, and `run` needs [robot] and
[plc]. Each refusal comes at load, names the key, the value and the range; the shipped configs still load as
they read.

The ranges below are the specification (docs/cell-config.md), written out here, not read from the loader.
"""

from __future__ import annotations

import re
import subprocess
import sys
import tomllib
from pathlib import Path
from typing import Any

import pytest

from monoguide.daemon.config import BOUNDS, CellConfig, load_cell_config, require_sections
from monoguide.daemon.config import _reader as config_reader
from monoguide.daemon.errors import ConfigMissingKey
from monoguide.drivers.errors import ConfigError

ROOT = Path(__file__).parents[3]
SHIPPED_SIM_CELL = ROOT / "config" / "sim-cell.toml"  # two part types ([[parts]])
# the simulated cell in the single-part form (the shipped file before it had part types): the text the mutations edit
SIM_CELL = ROOT / "tests" / "helpers" / "data" / "sim-cell-single-part.toml"
TEMPLATE = ROOT / "config" / "cell-template.toml"
VIKY = ROOT / "config" / "viky-camera.toml"
DOC = ROOT / "docs" / "cell-config.md"

# section, key, low, high, the range as the error message and the doc say it, where the loaded value is
RANGES: list[tuple[str, str, float, float, str, Any]] = [
    ("camera", "grab_timeout_s", 0.05, 60, "0.05 to 60 s", lambda c: c.camera.grab_timeout_s),
    ("camera", "exposure_us", 1, 10_000_000, "1 to 10000000 us", lambda c: c.camera.exposure_us),
    ("camera.intrinsics", "width", 1, 65535, "1 to 65535 px", lambda c: c.camera.intrinsics.width),
    ("camera.intrinsics", "height", 1, 65535, "1 to 65535 px", lambda c: c.camera.intrinsics.height),
    ("tracker", "baud", 300, 4_000_000, "300 to 4000000", lambda c: c.tracker.baud),
    ("tracker", "timeout_s", 0.05, 600, "0.05 to 600 s", lambda c: c.tracker.timeout_s),
    ("robot", "port", 1, 65535, "1 to 65535", lambda c: c.robot.port),
    ("robot", "connect_timeout_s", 0.05, 60, "0.05 to 60 s", lambda c: c.robot.connect_timeout_s),
    ("robot", "move_timeout_s", 0.05, 600, "0.05 to 600 s", lambda c: c.robot.move_timeout_s),
    ("robot", "ack_timeout_s", 0.05, 10, "0.05 to 10 s", lambda c: c.robot.ack_timeout_s),
    ("robot", "stale_timeout_s", 0.05, 10, "0.05 to 10 s", lambda c: c.robot.stale_timeout_s),
    ("robot", "rtde_frequency_hz", 1, 500, "1 to 500 Hz", lambda c: c.robot.rtde_frequency_hz),
    ("robot", "sim_move_time_s", 0, 60, "0 to 60 s", lambda c: c.robot.sim_move_time_s),
    ("plc", "port", 1, 65535, "1 to 65535", lambda c: c.plc.port),
    ("plc", "unit", 1, 255, "1 to 255", lambda c: c.plc.unit),
    ("plc", "base", 0, 65502, "0 to 65502", lambda c: c.plc.base),
    ("plc", "heartbeat_timeout_s", 0.1, 60, "0.1 to 60 s", lambda c: c.plc.heartbeat_timeout_s),
    ("plc", "timeout_s", 0.05, 60, "0.05 to 60 s", lambda c: c.plc.timeout_s),
    ("plc", "ack_timeout_s", 0.05, 600, "0.05 to 600 s", lambda c: c.plc.ack_timeout_s),
    ("service", "images_max_mb", 1, 10_000_000, "1 to 10000000 MB", lambda c: c.service.images_max_mb),
    ("service", "images_max_age_days", 0.01, 3650, "0.01 to 3650 days", lambda c: c.service.images_max_age_days),
    ("sim", "exposure_us_nominal", 1, 10_000_000, "1 to 10000000 us", lambda c: c.sim.exposure_us_nominal),
    ("calibration_target", "marks_cols", 2, 1000, "2 to 1000", lambda c: _marks_along(c, 0)),
    ("calibration_target", "marks_rows", 2, 1000, "2 to 1000", lambda c: _marks_along(c, 1)),
    ("checks", "check_visits", 1, 50, "1 to 50", lambda c: c.checks.check_visits),
]
INTEGER_KEYS = {"width", "height", "baud", "port", "unit", "base", "marks_cols", "marks_rows", "check_visits"}
RANGE_IDS = [f"{section}.{key}" for section, key, *_ in RANGES]


def _marks_along(config: CellConfig, axis: int) -> int:
    """How many distinct mark positions the target's grid has along its x (0) or y (1) axis."""
    assert config.calibration_target is not None
    return len({round(float(v), 6) for v in config.calibration_target.marks.centers_t[:, axis]})


def set_key(text: str, section: str, key: str, value: str) -> str:
    """``text`` with ``key = value`` in ``[section]`` (replacing the key's line, or added below the header)."""
    header = re.search(rf"^\[{re.escape(section)}\][^\n]*\n", text, flags=re.M)
    assert header is not None, f"no [{section}]"
    end = re.compile(r"^\[", flags=re.M).search(text, header.end())
    stop = end.start() if end else len(text)
    body = text[header.end():stop]
    line = re.compile(rf"^{re.escape(key)} = [^\n]*$", flags=re.M)
    body = line.sub(f"{key} = {value}", body, count=1) if line.search(body) else f"{key} = {value}\n{body}"
    return text[:header.end()] + body + text[stop:]


def drop_section(text: str, section: str) -> str:
    out = re.sub(rf"^\[{re.escape(section)}\][^\n]*\n.*?(?=^\[)", "", text, count=1, flags=re.S | re.M)
    assert f"[{section}]" not in out
    return out


def drop_pose(text: str, name: str) -> str:
    out = re.sub(rf"^\[\[measuring_poses\]\]\nname = \"{name}\".*?(?=^\[)", "", text, count=1, flags=re.S | re.M)
    assert f'name = "{name}"' not in out
    return out


def load_text(tmp_path: Path, text: str, name: str = "cell.toml") -> CellConfig:
    path = tmp_path / name
    path.write_text(text)
    return load_cell_config(path)


def _base_text(section: str, key: str) -> str:
    """The file a key is swept in: the template (every key but [sim]'s), the simulated cell for [sim]; a robot
    port other than 30004 needs a KUKA controller."""
    if section == "sim":
        return SIM_CELL.read_text()
    text = TEMPLATE.read_text()
    if (section, key) == ("robot", "port"):
        text = set_key(text, "robot", "backend", '"kuka"')
    if (section, key) == ("robot", "rtde_frequency_hz"):
        text = set_key(text, "robot", "stale_timeout_s", "10.0")  # two periods of 1 Hz fit
    return text


def _toml(value: float, integer: bool) -> str:
    return str(int(value)) if integer else repr(float(value))


# --- the range of every bounded key --------------------------------------------------------------------------


def test_the_loader_bounds_exactly_the_documented_keys() -> None:
    assert sorted(set(BOUNDS) - {"parts.job"}) == sorted(RANGE_IDS)  # [[parts]] job: tests/daemon/config/test_parts.py
    for section, key, low, high, said, _ in RANGES:
        assert str(BOUNDS[f"{section}.{key}"]) == said and (BOUNDS[f"{section}.{key}"].low,
                                                            BOUNDS[f"{section}.{key}"].high) == (low, high)


@pytest.mark.parametrize(("section", "key", "low", "high", "said", "read"), RANGES, ids=RANGE_IDS)
def test_a_value_outside_its_range_is_refused_naming_key_value_and_range(
        tmp_path: Path, section: str, key: str, low: float, high: float, said: str, read: Any) -> None:
    integer = key in INTEGER_KEYS
    base = _base_text(section, key)
    below = low - 1 if integer else (low / 2 if low > 0 else -0.001)
    above = high + 1 if integer else high * 1.5
    bad = [(_toml(below, integer), repr(int(below) if integer else float(below)), f"must be {said}"),
           (_toml(above, integer), repr(int(above) if integer else float(above)), f"must be {said}")]
    if integer:
        bad += [("nan", "nan", f"expected an integer ({said})"), (f"{low + 0.5}", repr(low + 0.5),
                                                                   f"expected an integer ({said})")]
    else:
        bad += [(v, v, f"must be {said}") for v in ("nan", "inf", "-inf")] + [("1e308", "1e+308", f"must be {said}")]
    for toml_value, shown, why in bad:
        with pytest.raises(ConfigError) as info:
            load_text(tmp_path, set_key(base, section, key, toml_value))
        assert info.value.code == "CONFIG_INVALID"
        assert f"[{section}].{key} = {shown}: {why}" in info.value.message, (toml_value, info.value.message)


@pytest.mark.parametrize(("section", "key", "low", "high", "said", "read"), RANGES, ids=RANGE_IDS)
def test_both_ends_of_a_range_are_accepted_as_written(tmp_path: Path, section: str, key: str, low: float,
                                                      high: float, said: str, read: Any) -> None:
    integer = key in INTEGER_KEYS
    for value in (low, high):
        text = set_key(_base_text(section, key), section, key, _toml(value, integer))
        assert read(load_text(tmp_path, text)) == value, (key, value)


def test_every_duration_and_count_the_loader_reads_has_a_range(monkeypatch: pytest.MonkeyPatch) -> None:
    """Keys named as durations or rates (_s, _us, _days, _hz, _mb) and every integer: a key added without a range
    fails here. The simulated cell's seed takes any non-negative integer; the [calibration] provenance is not
    configuration."""
    calls: list[tuple[str, str, bool, bool]] = []  # table, key, given a range, an integer
    number, integer = config_reader.ConfigTable.number, config_reader.ConfigTable.integer

    def recording(real: Any) -> Any:
        def getter(self: config_reader.ConfigTable, key: str, *args: Any, **kwargs: Any) -> Any:
            calls.append((self.name, key, kwargs.get("bounds") is not None, real is integer))
            return real(self, key, *args, **kwargs)
        return getter

    monkeypatch.setattr(config_reader.ConfigTable, "number", recording(number))
    monkeypatch.setattr(config_reader.ConfigTable, "integer", recording(integer))
    for path in (TEMPLATE, SIM_CELL, SHIPPED_SIM_CELL):
        load_cell_config(path)
    durations = re.compile(r".*_(s|us|days|hz|mb)$")
    unbounded = sorted({f"{name}.{key}" for name, key, bounded, is_int in calls
                        if not bounded and (is_int or durations.match(key))
                        and (name, key) != ("sim", "seed") and not name.startswith("calibration.")})
    assert calls and not unbounded, f"durations and counts without a documented range: {unbounded}"


def test_every_range_is_in_the_cell_config_doc() -> None:
    rows = [line for line in DOC.read_text().splitlines() if line.startswith("|")]
    for section, key, _low, _high, said, _ in RANGES:
        written = said.replace(" to ", "–")
        assert any(f"`{key}`" in row and written in row for row in rows), \
            f"docs/cell-config.md has no row for [{section}] {key} with its range {written}"


def test_too_many_measuring_poses(tmp_path: Path) -> None:
    text = TEMPLATE.read_text()
    start, end = text.index('[[measuring_poses]]\nname = "S3"'), text.index("\n[tracker]") + 1
    block = text[start:end]  # S3 and S4
    extra = "".join(block.replace('"S3"', f'"X{i}"').replace('"S4"', f'"Y{i}"') for i in range(48))
    assert len(load_text(tmp_path, text[:end] + extra + text[end:]).measuring_poses) == 100
    more = extra + block.replace('"S3"', '"Z1"').replace('"S4"', '"Z2"')
    with pytest.raises(ConfigError, match=r"\[\[measuring_poses\]\]: 102 poses: must be 1 to 100"):
        load_text(tmp_path, text[:end] + more + text[end:])


def test_a_ur_state_recipe_slower_than_its_stale_timeout_is_refused(tmp_path: Path) -> None:
    text = set_key(TEMPLATE.read_text(), "robot", "rtde_frequency_hz", "10.0")
    with pytest.raises(ConfigError, match=r"\[robot\]\.stale_timeout_s = 0\.1: must be at least two periods of "
                                          r"rtde_frequency_hz = 10 Hz \(0\.2 s\)"):
        load_text(tmp_path, set_key(text, "robot", "stale_timeout_s", "0.1"))
    assert load_text(tmp_path, set_key(text, "robot", "stale_timeout_s", "0.2")).robot.stale_timeout_s == 0.2
    kuka = set_key(set_key(text, "robot", "backend", '"kuka"'), "robot", "port", "54600")
    assert load_text(tmp_path, set_key(kuka, "robot", "stale_timeout_s", "0.1")).robot.stale_timeout_s == 0.1


# --- the mutations that used to start the service ------------------------------------------------------------


def _three_holes(text: str) -> str:
    text = drop_pose(text, "S4")
    text = re.sub(r"^points_w = .*$", "points_w = [[0.0, 0.0, 0.0], [1218.078, 0.0, 0.0], [1218.028, 2058.764, 0.0]]",
                  text, count=1, flags=re.M)
    return text.replace('point_names = ["P1", "P2", "P3", "P4"]', 'point_names = ["P1", "P2", "P3"]', 1)


def _second_pose(text: str, old: str, new: str) -> str:
    start = text.index('[[measuring_poses]]\nname = "S2"')
    return text[:start] + text[start:].replace(old, new, 1)


MUTATIONS = {
    "plc ack_timeout_s = 1e308": (lambda t: set_key(t, "plc", "ack_timeout_s", "1e308"),
                                  r"\[plc\]\.ack_timeout_s = 1e\+308: must be 0\.05 to 600 s"),
    "robot ack_timeout_s = 1e308": (lambda t: set_key(t, "robot", "ack_timeout_s", "1e308"),
                                    r"\[robot\]\.ack_timeout_s = 1e\+308: must be 0\.05 to 10 s"),
    "heartbeat_timeout_s = 1e308": (lambda t: set_key(t, "plc", "heartbeat_timeout_s", "1e308"),
                                    r"\[plc\]\.heartbeat_timeout_s = 1e\+308: must be 0\.1 to 60 s"),
    "heartbeat_timeout_s = 0.001": (lambda t: set_key(t, "plc", "heartbeat_timeout_s", "0.001"),
                                    r"\[plc\]\.heartbeat_timeout_s = 0\.001: must be 0\.1 to 60 s"),
    "duplicated pose names": (lambda t: _second_pose(t, 'name = "S2"', 'name = "S1"'),
                              r"\[\[measuring_poses\]\] #2\.name = 'S1': already the name of "
                              r"\[\[measuring_poses\]\] #1"),
    "empty pose name": (lambda t: _second_pose(t, 'name = "S2"', 'name = ""'),
                        r"\[\[measuring_poses\]\] #2\.name = '': must not be empty"),
    "points = []": (lambda t: _second_pose(t, "points = [1]", "points = []"),
                    r"\[\[measuring_poses\]\] #2\.points = \[\]: a measuring pose sees at least one featured hole"),
    "a part with 3 holes": (_three_holes,
                            r"\[\[measuring_poses\]\] S1, S2, S3: see 3 hole image\(s\) of \[part\] \(P1 in S1, P2 in "
                            r"S2, P3 in S3\); the pose solver needs at least 4: .* 2 x 3 - 6 = 0 degrees of freedom"),
    "empty plc.host": (lambda t: set_key(t, "plc", "host", '""'),
                       r"\[plc\]\.host = '': empty: expected an IP address or a host name"),
    "empty cell.name": (lambda t: set_key(t, "cell", "name", '""'), r"\[cell\]\.name = '': must not be empty"),
    "plc host = 256.1.1.1": (lambda t: set_key(t, "plc", "host", '"256.1.1.1"'),
                             r"\[plc\]\.host = '256\.1\.1\.1': not an IPv4 address \(Octet 256 \(> 255\)"),
    "robot host = 256.1.1.1": (lambda t: set_key(t, "robot", "host", '"256.1.1.1"'),
                               r"\[robot\]\.host = '256\.1\.1\.1': not an IPv4 address"),
}


@pytest.mark.parametrize("mutation", sorted(MUTATIONS))
def test_each_mutation_is_refused_at_load(tmp_path: Path, mutation: str) -> None:
    change, message = MUTATIONS[mutation]
    text = change(SIM_CELL.read_text())
    assert text != SIM_CELL.read_text()
    with pytest.raises(ConfigError, match=message) as info:
        load_text(tmp_path, text)
    assert (info.value.code, info.value.plc_code) == ("CONFIG_INVALID", 500)


def test_run_needs_robot_and_plc(tmp_path: Path) -> None:
    """`run` without [robot] retried forever; without [plc] it said CONFIG_INVALID where a section is missing."""
    require_sections(load_cell_config(SIM_CELL), ("robot", "plc"), command="run")
    for section in ("robot", "plc"):
        cfg = load_text(tmp_path, drop_section(SIM_CELL.read_text(), section))  # loads: other commands need neither
        assert getattr(cfg, section) is None
        with pytest.raises(ConfigMissingKey, match=rf"\[{section}\]: missing, a section `monoguide run` needs") as info:
            require_sections(cfg, ("robot", "plc"), command="run")
        assert (info.value.code, info.value.plc_code) == ("CONFIG_MISSING_KEY", 532)
    with pytest.raises(ValueError, match="'robots' is not an optional section"):
        require_sections(load_cell_config(SIM_CELL), ("robots",), command="run")


@pytest.mark.parametrize(("mutation", "says"), [
    ("heartbeat_timeout_s = 0.001", "[plc].heartbeat_timeout_s = 0.001: must be 0.1 to 60 s"),
    ("duplicated pose names", "[[measuring_poses]] #2.name = 'S1'"),
    ("plc host = 256.1.1.1", "[plc].host = '256.1.1.1': not an IPv4 address"),
])
def test_monoguide_run_exits_2_at_load(tmp_path: Path, mutation: str, says: str) -> None:
    config = tmp_path / "cell.toml"
    config.write_text(MUTATIONS[mutation][0](SIM_CELL.read_text()))
    done = subprocess.run([sys.executable, "-m", "monoguide.daemon.cli", "run", "--config", str(config),
                           "--state-dir", str(tmp_path / "state")], capture_output=True, text=True, timeout=60)
    assert done.returncode == 2, done.stderr
    assert "CONFIG_INVALID" in done.stderr and says in done.stderr, done.stderr
    assert not (tmp_path / "state").exists()  # refused before anything started


# --- names ---------------------------------------------------------------------------------------------------


@pytest.mark.parametrize(("change", "message"), [
    (lambda t: set_key(t, "cell", "name", '"   "'), r"\[cell\]\.name = '   ': must not be empty"),
    (lambda t: set_key(t, "part", "point_names", '["P1", "P2", "P2", "P4"]'),
     r"\[part\]\.point_names = \['P1', 'P2', 'P2', 'P4'\]: 'P2' names two points"),
    (lambda t: set_key(t, "part", "point_names", '["P1", "", "P3", "P4"]'),
     r"\[part\]\.point_names = .*: name #2 is empty"),
    (lambda t: _second_pose(t, "points = [1]", "points = [1, 1]"),
     r"#2\.points = \[1, 1\]: \[1\] listed twice"),
    (lambda t: t.replace('name = "T2"', 'name = "T1"', 1), r"\[\[sim\.targets\]\] #2\.name = 'T1': another"),
    (lambda t: t.replace('name = "T2"', 'name = ""', 1), r"\[\[sim\.targets\]\] #2\.name = '': must not be empty"),
    (lambda t: set_key(t, "camera", "pixel_format", '""'), r"\[camera\]\.pixel_format = '': must not be empty"),
    (lambda t: set_key(t, "tracker", "port", '""'), r"\[tracker\]\.port = '': must not be empty"),
    (lambda t: t.replace("[sim.benchmarks]", '[sim.benchmarks]\n"" = [1.0, 2.0, 3.0]', 1),
     r"\[sim\.benchmarks\]: a nest with an empty name"),
    (lambda t: set_key(t, "cell_frame", "benchmarks", '{ B1 = [0.0, 0.0, 0.0], "" = [1500.0, 0.0, 0.0], '
                                                      'B3 = [0.0, 1200.0, 0.0] }'),
     r"\[cell_frame\.benchmarks\]: a nest with an empty name"),
], ids=["blank cell name", "point names twice", "empty point name", "a hole twice in a view", "target names twice",
        "empty target name", "empty pixel format", "empty tracker port", "empty sim nest", "empty cell-frame nest"])
def test_names_are_non_empty_and_unique(tmp_path: Path, change: Any, message: str) -> None:
    text = change(SIM_CELL.read_text())
    assert text != SIM_CELL.read_text()
    with pytest.raises(ConfigError, match=message):
        load_text(tmp_path, text)


# --- hosts ---------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("host", ["10.0.0.5", "192.168.10.30", "::1", "fe80::1%eth0", "2001:db8::30", "h",
                                  "localhost", "plc-3.line.example.com", "plc3.", "3com.example", "a" * 63])
def test_addresses_and_host_names_are_accepted(tmp_path: Path, host: str) -> None:
    text = set_key(set_key(SIM_CELL.read_text(), "plc", "host", f'"{host}"'), "robot", "host", f'"{host}"')
    cfg = load_text(tmp_path, text)
    assert cfg.plc is not None and cfg.robot is not None and cfg.plc.host == cfg.robot.host == host


@pytest.mark.parametrize(("host", "why"), [
    ("", "empty: expected an IP address or a host name"),
    ("  ", "empty"),
    ("256.1.1.1", r"not an IPv4 address \(Octet 256 \(> 255\) not permitted"),
    ("10.0.1", r"not an IPv4 address \(Expected 4 octets"),
    ("10.0.0.05", "not an IPv4 address"),
    ("[::1]", r"not an IPv6 address: write it without the brackets"),
    ("fe80::g", "not an IPv6 address"),
    ("-plc", r"not a host name: label '-plc'"),
    ("plc-", r"not a host name: label 'plc-'"),
    ("plc_3", r"not a host name: label 'plc_3'"),
    ("plc 3", r"not a host name: label 'plc 3'"),
    ("plc..line", r"not a host name: label ''"),
    ("a" * 64, "not a host name: label 'a{64}'"),
    (".".join(["a" * 63] * 4) + ".b", "a host name of 257 characters"),
    ("10.0.0.5:502", "a host with a port: give the port in its own key"),
    ("plc3.line:502", "a host with a port: give the port in its own key"),
])
def test_a_bad_host_is_refused_saying_why(tmp_path: Path, host: str, why: str) -> None:
    for section in ("plc", "robot"):
        with pytest.raises(ConfigError, match=rf"\[{section}\]\.host = {re.escape(repr(host))}: {why}"):
            load_text(tmp_path, set_key(SIM_CELL.read_text(), section, "host", f'"{host}"'))


# --- the redundancy the pose solver needs --------------------------------------------------------------------


def test_a_hole_seen_twice_makes_up_the_redundancy(tmp_path: Path) -> None:
    """Three holes, four views (P3 in S3 and S4): 4 hole images, 2 degrees of freedom for the check."""
    text = _three_holes(SIM_CELL.read_text())
    s3 = text[text.index('[[measuring_poses]]\nname = "S3"'):text.index("[cell_frame]")]
    cfg = load_text(tmp_path, text.replace("[cell_frame]", s3.replace('"S3"', '"S4"', 1) + "[cell_frame]", 1))
    assert [p.points for p in cfg.measuring_poses] == [(0,), (1,), (2,), (2,)]


def test_four_images_of_two_holes_are_refused(tmp_path: Path) -> None:
    text = SIM_CELL.read_text()
    for old, new in (("points = [2]", "points = [0]"), ("points = [3]", "points = [1]")):
        text = text.replace(old, new, 1)
    with pytest.raises(ConfigError, match=r"S1, S2, S3, S4: see 2 distinct hole\(s\) of \[part\] \(P1, P2\); the pose "
                                          r"needs at least 3 holes not on one line"):
        load_text(tmp_path, text)


def test_holes_on_one_line_are_refused(tmp_path: Path) -> None:
    text = re.sub(r"^points_w = .*$", "points_w = [[0.0, 0.0, 0.0], [1000.0, 0.0, 0.0], [2000.0, 0.0, 0.0], "
                  "[500.0, 0.0, 0.0]]", SIM_CELL.read_text(), count=1, flags=re.M)
    with pytest.raises(ConfigError, match=r"the holes they see \(P1, P2, P3, P4\) lie on one line"):
        load_text(tmp_path, text)
    off = text.replace("[500.0, 0.0, 0.0]]", "[500.0, 5.0, 0.0]]", 1)
    assert len(load_text(tmp_path, off).part.points_w) == 4


def test_a_cell_without_robot_and_plc_may_have_fewer_holes() -> None:
    """The camera-probe config (one hole, one view, no [robot], no [plc]) runs no cycle: it still loads."""
    cfg = load_cell_config(VIKY)
    assert len(cfg.part.points_w) == 1 and cfg.robot is None and cfg.plc is None


def test_the_redundancy_is_checked_with_plc_alone(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"see 3 hole image\(s\)"):
        load_text(tmp_path, drop_section(_three_holes(SIM_CELL.read_text()), "robot"))


# --- the shipped configs still load as they read -------------------------------------------------------------


@pytest.mark.parametrize("path", [SHIPPED_SIM_CELL, SIM_CELL, VIKY, TEMPLATE], ids=lambda p: p.name)
def test_the_shipped_configs_load_unchanged_in_meaning(path: Path) -> None:
    raw = tomllib.loads(path.read_text())
    cfg = load_cell_config(path)
    assert cfg.name == raw["cell"]["name"]
    assert [p.name for p in cfg.cell_poses] == [p.get("name", f"S{i + 1}")
                                                for i, p in enumerate(raw["measuring_poses"])]
    checked = 0
    for section, key, *_, read in RANGES:
        table: Any = raw
        for part in section.split("."):
            table = table.get(part, {})
        if key in table and not key.startswith("marks_"):
            assert read(cfg) == table[key], f"[{section}] {key}"
            checked += 1
    for section in ("robot", "plc"):
        if section in raw and "host" in raw[section]:
            assert getattr(cfg, section).host == raw[section]["host"]
    assert checked >= (1 if path == VIKY else 10)
