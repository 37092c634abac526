"""The calibration file's text-level editor as monoguide had it before ``tomlkit``: the reference the document
writer (``daemon/calibrate/_file.py``) is compared with on the committed configs.

It edits the TEXT by offsets: a calibrated key's value is spliced in place (a comment after a matrix's opening
bracket kept), a key the file lacks is added after the last entry of its table, the ``[calibration]`` tables are
cut and the new block put where the first one was (the comment lines directly above the next table, even one
inside the section, are left standing). :func:`edit_calibration_text` is fed the same calibrated values and
provenance as the writer (``calibration_file._calibrated_values``, ``calibration_file._provenance``), so the two
differ only in how they edit. Kept as it was, apart from this entry point; do not use it to write files.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from monoguide.daemon.errors import CalibrationFileUneditable
from monoguide.drivers.toml_format import MATRIX_DECIMALS


def edit_calibration_text(text: str, values: dict[tuple[str, int, str], tuple[str, Any]], record: dict[str, Any],
                          path: Path) -> str:
    """``text`` with the calibrated ``values`` ((table, index, key) -> (kind, value)) and the ``[calibration]``
    section ``record`` written as the text-level editor wrote them."""
    doc = _Document(text, path)
    for (table, index, key), (kind, value) in values.items():
        doc.set(table, index, key, _format(kind, value))
    doc.replace_tables("calibration", _provenance_block(record))
    return doc.text


def _provenance_block(record: dict[str, Any]) -> str:
    lines = ["[calibration]  # written by `monoguide calibrate` (docs/calibration.md, \"The calibration file\")",
             f"date = {_string(record['date'])}"]
    if "session" in record:
        lines.append(f"session = {_string(record['session'])}")
    lines.append(f"wizard_version = {_string(record['wizard_version'])}")
    lines.append(f"previous = {_string(record['previous'])}  # this file before the calibration; roll back by "
                 f"copying it here")
    if "sim" in record:
        lines.append(f"sim = {_value(record['sim'])}")
    if record.get("devices"):
        lines += ["", "[calibration.devices]"] + [f"{_key(k)} = {_string(v)}" for k, v in record["devices"].items()]
    if record.get("steps"):
        lines += ["", "[calibration.steps]  # per step: when, and its residual summary"]
        for name, summary in record["steps"].items():
            items = ", ".join(f"{_key(k)} = {_value(v)}" for k, v in summary.items())
            lines.append(f"{name} = {{ {items} }}" if items else f"{name} = {{}}")
    return "\n".join(lines) + "\n"


def _value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return _string(value)
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        return repr(value)
    return "[" + ", ".join(_value(float(v)) for v in value) + "]"


def _string(value: str) -> str:
    return json.dumps(value, ensure_ascii=False)  # JSON's escapes are TOML's basic-string escapes


def _key(key: str) -> str:
    bare = key and all(c.isascii() and (c.isalnum() or c in "_-") for c in key)
    return key if bare else _string(key)


def _format(kind: str, value: Any) -> str:
    if kind == "integer":
        return str(value)
    if kind == "number":
        return repr(float(value))
    rows = ",\n    ".join("[" + ", ".join(f"{v:.{MATRIX_DECIMALS}f}" for v in row) + "]" for row in value)
    return "[\n    " + rows + ",\n]"


@dataclass
class _Header:
    name: str
    index: int  # the entry of an array of tables ([[name]]), -1 for a table
    start: int  # offset of its line
    end: int  # offset after its line


@dataclass
class _Entry:
    table: str
    index: int
    key: str  # as written, dotted keys joined by "."
    value_start: int
    value_end: int
    line_end: int  # offset after the line the value ends on


class _Document:
    """A TOML text scanned into headers and key/value entries, edited by offsets."""

    def __init__(self, text: str, path: Path) -> None:
        self.text, self.path = text, path
        self._scan()

    def set(self, table: str, index: int, key: str, value: str) -> None:
        entry = next((e for e in self.entries if e.table == table and e.index == index and e.key == key), None)
        if entry is not None:
            old = self.text[entry.value_start:entry.value_end]
            if "\n" in value and old.startswith("[") and "\n" in old:  # keep a comment after the opening bracket
                first = old.split("\n", 1)[0]
                if "#" in first:
                    value = "[  " + first[first.index("#"):].rstrip() + value[1:]
            self._splice(entry.value_start, entry.value_end, value)
            return
        header = next((h for h in self.headers if h.name == table and h.index == index), None)
        if header is None:
            where = f"[[{table}]] #{index + 1}" if index >= 0 else f"[{table}]"
            raise CalibrationFileUneditable(f"{self.path}: {where} is not written as a table header the calibration "
                                            f"can edit ({key} cannot be set); write it as {where}")
        last = [e for e in self.entries if e.table == table and e.index == index]
        at = last[-1].line_end if last else header.end
        line = f"{key} = {value}\n"
        if at > 0 and self.text[at - 1] != "\n":
            line = "\n" + line
        self._splice(at, at, line)

    def replace_tables(self, name: str, block: str) -> None:
        """Remove every ``[name]`` / ``[name.*]`` table and put ``block`` where the first was (else at the end)."""
        spans = []
        for i, h in enumerate(self.headers):
            if h.name == name or h.name.startswith(name + "."):
                end = self._attached_start(self.headers[i + 1].start) if i + 1 < len(self.headers) else len(self.text)
                spans.append((h.start, max(end, h.end)))
        if not spans:
            self.text = self.text.rstrip("\n") + "\n\n" + block
        else:
            for start, end in reversed(spans[1:]):
                self._splice(start, end, "")
            start, end = spans[0]
            rest = self.text[end:]
            self._splice(start, end, block + ("\n" if rest.strip() else ""))
        self._scan()

    # --- private -------------------------------------------------------------------------------

    def _splice(self, start: int, end: int, new: str) -> None:
        self.text = self.text[:start] + new + self.text[end:]
        self._scan()

    def _attached_start(self, offset: int) -> int:
        """Where the comment lines directly above the line at ``offset`` begin (they belong to it)."""
        start = offset
        while start > 0:
            prev = self.text.rfind("\n", 0, start - 1) + 1
            if not self.text[prev:start].strip().startswith("#"):
                break
            start = prev
        return start

    def _scan(self) -> None:
        text, n = self.text, len(self.text)
        self.headers: list[_Header] = []
        self.entries: list[_Entry] = []
        table, index, counts = "", -1, {}
        i = 0
        while i < n:
            j = i
            while j < n and text[j] in " \t":
                j += 1
            if j >= n or text[j] in "\r\n#":
                i = _eol(text, j)
                continue
            if text[j] == "[":
                array = text.startswith("[[", j)
                close = text.find("]]" if array else "]", j)
                if close < 0:
                    raise CalibrationFileUneditable(f"{self.path}: a table header without its closing bracket")
                table = ".".join(p.strip().strip('"') for p in text[j + (2 if array else 1):close].split("."))
                index = counts.get(table, 0) if array else -1
                if array:
                    counts[table] = index + 1
                end = _eol(text, close)
                self.headers.append(_Header(table, index, i, end))
                i = end
                continue
            eq = _key_end(text, j)
            key = ".".join(p.strip().strip('"') for p in text[j:eq].split("."))
            start = eq + 1
            while start < n and text[start] in " \t":
                start += 1
            stop = _value_end(text, start)
            self.entries.append(_Entry(table, index, key, start, stop, _eol(text, stop)))
            i = _eol(text, stop)


def _eol(text: str, i: int) -> int:
    """Offset after the newline that ends the line holding offset ``i``."""
    k = text.find("\n", i)
    return len(text) if k < 0 else k + 1


def _key_end(text: str, i: int) -> int:
    while i < len(text) and text[i] != "=":
        if text[i] in "\"'":
            i = text.find(text[i], i + 1)
            if i < 0:
                break
        if text[i] == "\n":
            break
        i += 1
    if i >= len(text) or i < 0 or text[i] != "=":
        raise CalibrationFileUneditable("a line is neither a table header nor key = value")
    return i


def _string_end(text: str, i: int) -> int:
    """Offset after the string starting at ``i``."""
    for quote in ('"""', "'''"):
        if text.startswith(quote, i):
            k = i + 3
            while True:
                k = text.find(quote, k)
                if k < 0:
                    return len(text)
                if quote == "'''" or text[k - 1] != "\\":
                    while text.startswith(quote[0], k + 3):  # up to two quotes may close the content
                        k += 1
                    return k + 3
                k += 1
    quote, k = text[i], i + 1
    while k < len(text) and text[k] != quote and text[k] != "\n":
        k += 2 if quote == '"' and text[k] == "\\" else 1
    return k + 1


def _value_end(text: str, i: int) -> int:
    """Offset after the value starting at ``i`` (arrays and inline tables may span lines)."""
    n = len(text)
    if i < n and text[i] in "\"'":
        return _string_end(text, i)
    if i < n and text[i] in "[{":
        depth = 0
        while i < n:
            c = text[i]
            if c in "\"'":
                i = _string_end(text, i)
                continue
            if c == "#":
                i = _eol(text, i)
                continue
            if c in "[{":
                depth += 1
            elif c in "]}":
                depth -= 1
                if depth == 0:
                    return i + 1
            i += 1
        return n
    k = i
    while k < n and text[k] not in "#\r\n":
        k += 1
    while k > i and text[k - 1] in " \t":
        k -= 1
    return k
