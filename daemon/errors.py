"""Every failure the daemon reports itself, one class each, with its stable ``code`` and its PLC ``plc_code``.

The device and configuration failures are the drivers' (``monoguide.drivers.errors``), the solver's its own
(``monoguide.solver.errors``); these are the cycle's, the service's, the journal's, the wizard's, ``simulate``'s
and the commands'. docs/plc-interface.md's table of codes is generated from all of them
(``tests/drivers/test_plc_interface_doc.py --write``).

``plc_code`` ranges: 530-539 the cell config, 600-609 the cycle, 610-619 the service, 620-629 the journal,
640-649 the state directory and the readers, 650-659 ``simulate``, 660 ``init``, 670-679 the operator page
(``monoguide web``), 680-689 ``monoguide plant`` (OPC UA and metrics), 700-729 the calibration wizard.
"""

from __future__ import annotations

from monoguide.drivers.errors import ConfigError
from monoguide.solver.calibration.errors import CalibrationError
from monoguide.solver.errors import MonoguideError


class ConfigUnknownKey(ConfigError):
    """A key the section does not have (a typo, or a key of another section); the message suggests the
    closest known key."""

    code = "CONFIG_UNKNOWN_KEY"
    plc_code = 530


class ConfigUnknownSection(ConfigError):
    """A section (``[name]``) the cell config does not have; the message suggests the closest known one."""

    code = "CONFIG_UNKNOWN_SECTION"
    plc_code = 531


class ConfigMissingKey(ConfigError):
    """A required key (or section) is absent; nothing is ever filled in for it."""

    code = "CONFIG_MISSING_KEY"
    plc_code = 532


class ConfigFileRefused(ConfigError):
    """A file given as a config is not a regular file (a named pipe, a device, a directory, ...) or is larger than
    the limit (4 MiB): refused unread; the message names the path and what it is."""

    code = "CONFIG_FILE_REFUSED"
    plc_code = 533


class CycleError(MonoguideError):
    """The measuring cycle failed in a way that is not a device's or the solver's fault."""

    code = "CYCLE_ERROR"
    plc_code = 600


class IllegalTransition(CycleError):
    """A cause happened in a state where the transition table does not allow it: a bug, never ignored."""

    code = "CYCLE_ILLEGAL_TRANSITION"
    plc_code = 601


class CycleAborted(CycleError):
    """The service stopped mid-cycle (SIGTERM): nothing was written to the robot."""

    code = "CYCLE_ABORTED"
    plc_code = 602


class CycleUnexpected(CycleError):
    """An exception no stage should raise (a bug) ended the cycle: it is journaled with the stage, the exception's
    type and message, the PLC sees DONE + ERROR with this code, nothing is written to the robot (an offset already
    sent is settled as after any failed write), and the service log has the traceback."""

    code = "CYCLE_UNEXPECTED"
    plc_code = 605


class PartNotCalibrated(CycleError):
    """The job's part type has not been calibrated by the wizard (``monoguide calibrate --job N``) in a cell whose
    other parts have: its jobs are refused, the message names the job, the part and the missing steps."""

    code = "PART_NOT_CALIBRATED"
    plc_code = 604  # 603 was CYCLE_CAPTURE_POSE_MISMATCH (retired, never reused)



class NotifySocketInvalid(MonoguideError):
    """``$NOTIFY_SOCKET`` is neither a path nor an abstract socket name (``@...``); e.g. a ``vsock:`` address."""

    code = "NOTIFY_SOCKET_INVALID"
    plc_code = 610


class JournalError(MonoguideError):
    """The journal could not be opened, read or written; the message names the file and SQLite's words."""

    code = "JOURNAL_ERROR"
    plc_code = 620


class JournalNotADatabase(JournalError):
    """The journal file exists but is not an SQLite database (corrupt, truncated, or some other file)."""

    code = "JOURNAL_NOT_A_DATABASE"
    plc_code = 621


class JournalSchemaUnknown(JournalError):
    """An SQLite file that is not a monoguide journal, or one of a schema version this release cannot read."""

    code = "JOURNAL_SCHEMA_UNKNOWN"
    plc_code = 622


class JournalEntryMissing(JournalError):
    """No cycle with that number in the journal."""

    code = "JOURNAL_ENTRY_MISSING"
    plc_code = 623


class JournalEntryInvalid(JournalError):
    """A cycle entry that contradicts itself (ok without a result, error without a code); nothing written."""

    code = "JOURNAL_ENTRY_INVALID"
    plc_code = 624


class JournalReplaced(JournalError):
    """The journal file was deleted or replaced while the service ran: nothing more is committed to it, no
    offset is written; FAULT stays latched until the service is restarted (which opens the journal anew)."""

    code = "JOURNAL_REPLACED"
    plc_code = 625


class StateDirMissing(MonoguideError):
    """The state directory does not exist (wrong --state-dir, or the service never ran)."""

    code = "STATE_DIR_MISSING"
    plc_code = 640


class ServiceStatusInvalid(MonoguideError):
    """The status file exists but cannot be read or is not a ``monoguide.status/1`` object."""

    code = "SERVICE_STATUS_INVALID"
    plc_code = 641


class NoJournal(JournalError):
    """The state directory has no journal: the service has not committed a cycle there."""

    code = "JOURNAL_MISSING"
    plc_code = 642


class CycleWithoutRecord(JournalError):
    """The cycle failed before its measurement record existed, so there is nothing to solve again."""

    code = "JOURNAL_NO_RECORD"
    plc_code = 643


class StateDirInUse(MonoguideError):
    """Another service holds this state directory (its lock file is locked); the message names its PID."""

    code = "STATE_DIR_IN_USE"
    plc_code = 644


class StateDirInvalid(MonoguideError):
    """The state directory cannot be one: ``--state-dir`` empty (never taken for the current directory), a file or
    anything else that is not a directory there (or where one of its parents should be), or it cannot be created;
    the message names it and where it came from (``--state-dir``, ``$STATE_DIRECTORY``)."""

    code = "STATE_DIR_INVALID"
    plc_code = 645


class SimulateError(MonoguideError):
    """The simulated run itself failed (not a cycle: the cell or the service would not start, or hung)."""

    code = "SIMULATE_ERROR"
    plc_code = 650


class SimulateTimeout(SimulateError):
    """A wait of the simulated run ran out; the message says for what and what the service last logged."""

    code = "SIMULATE_TIMEOUT"
    plc_code = 651


class SimulateChildEnded(SimulateError):
    """The simulated cell or the service ended before the run was over; the message has its last log lines."""

    code = "SIMULATE_CHILD_ENDED"
    plc_code = 652


class InitFailed(MonoguideError):
    """``monoguide init`` wrote nothing: a file exists (without --force) or cannot be written; the message names it."""

    code = "INIT_FAILED"
    plc_code = 660


class CalibrationAborted(MonoguideError):
    """The person at the cell ended the wizard at a prompt (end of input); the session keeps what was done."""

    code = "CALIBRATION_ABORTED"
    plc_code = 706


class CalibrationSessionInvalid(MonoguideError):
    """The session file cannot be used: unreadable, of another format, or made for another cell or options."""

    code = "CALIBRATION_SESSION_INVALID"
    plc_code = 707


class CalibrationStepNotReady(MonoguideError):
    """A calibration step was asked for before the steps it needs were done."""

    code = "CALIBRATION_STEP_NOT_READY"
    plc_code = 708


class CalibrationMeasurementFailed(CalibrationError):
    """A camera measurement of the part during the verification or the accuracy validation failed (a hole not
    found, an inconsistent solve); the message says which measurement and why."""

    code = "CALIBRATION_MEASUREMENT_FAILED"
    plc_code = 713


class CalibrationNoTarget(CalibrationError):
    """The cell config does not say which target the measuring poses are calibrated with (no
    ``[calibration_target]``)."""

    code = "CALIBRATION_NO_TARGET"
    plc_code = 714


class SimRigError(MonoguideError):
    """The simulated cell of ``calibrate --sim`` would not start (its process ended, or did not say in time
    that its devices listen); the message has the end of its log."""

    code = "SIM_RIG_ERROR"
    plc_code = 720


class SimRigConfigError(SimRigError):
    """The truth config cannot be the simulated cell of ``calibrate --sim`` (no ``[sim]``, no simulated robot
    or tracker, no SMR on the flange tool, no calibration targets)."""

    code = "SIM_RIG_CONFIG"
    plc_code = 721


class CalibrationFileError(CalibrationError):
    """The cell config could not be read, copied or written (the message has the OS's reason)."""

    code = "CALIBRATION_FILE_FAILED"
    plc_code = 725


class CalibrationFileRefused(CalibrationFileError):
    """The rewritten config would not load (or not hold the calibrated values): nothing was replaced."""

    code = "CALIBRATION_FILE_REFUSED"
    plc_code = 726


class CalibrationValueInvalid(CalibrationFileError):
    """A step's result or the provenance cannot be written: not a rigid 4x4, a missing coefficient, a measuring
    pose the config does not have, an unknown provenance key."""

    code = "CALIBRATION_VALUE_INVALID"
    plc_code = 727


class CalibrationFileUneditable(CalibrationFileError):
    """The config is not a TOML file the calibration can be written into: not valid TOML (or not UTF-8), or a
    calibrated key's table is missing or not a table (``camera = 5``); the message names it.

    Tables written inline (``intrinsics = { ... }``) or out of order are edited like any other, so a file the
    loader accepts is never uneditable: every table the calibration writes into is one it requires."""

    code = "CALIBRATION_FILE_UNEDITABLE"
    plc_code = 728


class CalibrationReportFailed(CalibrationError):
    """The report could not be written (the directory is not writable); the calibration itself stands."""

    code = "CALIBRATION_REPORT_FAILED"
    plc_code = 729


class OutputNotWritten(MonoguideError):
    """A file a command was asked to write (``--out``, ``--write``) could not be written; the message names it
    and the system's reason. What else the command had to do was done."""

    code = "OUTPUT_NOT_WRITTEN"
    plc_code = 661


class WebConfigError(ConfigError):
    """``monoguide web`` cannot start as asked (a usage error: exit 2, nothing served)."""

    code = "WEB_CONFIG_INVALID"
    plc_code = 670


class WebAuthRequired(WebConfigError):
    """A ``--bind`` address other than loopback without ``--users`` or ``--token-file``: the page would be open
    to the plant network."""

    code = "WEB_AUTH_REQUIRED"
    plc_code = 671


class WebCredentialsInvalid(WebConfigError):
    """The users file or the token file cannot be read or is not in its format (the message names the line)."""

    code = "WEB_CREDENTIALS_INVALID"
    plc_code = 672


class WebServerFailed(MonoguideError):
    """The page's server could not listen (the address in use, not this machine's) or ended on an error."""

    code = "WEB_SERVER_FAILED"
    plc_code = 673


class PlantCertificateError(MonoguideError):
    """``monoguide plant``: the OPC UA server's certificate or key cannot be made or read, or the key is readable by
    others, or a file of the trust list is no certificate."""

    code = "PLANT_CERTIFICATE"
    plc_code = 680


class PlantListenFailed(MonoguideError):
    """``monoguide plant``: the OPC UA or the metrics port cannot be listened on (in use, or an address this PC
    does not have)."""

    code = "PLANT_LISTEN_FAILED"
    plc_code = 681


class PlantMetricsAuthRequired(ConfigError):
    """``monoguide plant``: ``[plant] metrics_host`` other than loopback without both TLS and basic authentication
    (``[plant.metrics_web]``): the metrics would be open to the plant network in clear text."""

    code = "PLANT_METRICS_AUTH_REQUIRED"
    plc_code = 682


class PlantNodeSetInvalid(ConfigError):
    """``monoguide plant``: ``[plant] machine_vision_nodeset`` missing, or not the OPC Foundation's Machine Vision
    NodeSet2 file (model 1.0.0) that the OPC UA server is built from."""

    code = "PLANT_NODESET"
    plc_code = 683


def drop_tracebacks(error: BaseException | None) -> None:
    """Let go of what ``error`` holds through its traceback, and through those of its cause and context: the frames
    of every stage it passed, with their images and arrays (tens of MB for a hole not found). A finished cycle's
    error is kept (the state machine's history, a device's last error) as its code and message, never with the
    frames."""
    seen: set[int] = set()
    chain = [error]
    while chain:
        link = chain.pop()
        if link is None or id(link) in seen:
            continue
        seen.add(id(link))
        link.__traceback__ = None
        chain += [link.__cause__, link.__context__]
