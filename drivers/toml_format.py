"""How monoguide writes TOML: tomlkit items that print as the cell files are laid out, and edits of a parsed
file that keep its comments where they belong.

A matrix is one row per line with a fixed number of decimals (:data:`MATRIX_DECIMALS`: a round trip through
the text is exact to ~1e-12, in mm and in rotation entries)::

    T_cf_w0 = [
        [-0.999843245114, -0.013051337092, -0.011994924081, -1381.259000000000],
        ...
    ]

Short lists of numbers stay on one line. Every item is a tomlkit item, so it can be put into a parsed document
beside its comments, or into a new one.

tomlkit files the comment lines above a table header under the table before it: a key appended to that table
lands below them, and a table replaced takes them along (python-poetry/tomlkit#295).
:func:`add_after_last_value` and :func:`replace_section` keep such comments above the table they introduce, with
tomlkit's public API only (no private method of tomlkit, which may go in any release: tests/test_private_api.py).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, MutableMapping, Sequence
from typing import Any

import tomlkit
from tomlkit import TOMLDocument
from tomlkit.items import AoT, Array, Comment, InlineTable, Item, Table, Whitespace

__all__ = ["MATRIX_DECIMALS", "add_after_last_value", "commented", "inline_table", "matrix", "number", "numbers",
           "opening_comment", "replace_section"]

MATRIX_DECIMALS = 12
ROW_INDENT = "    "
COMMENT_GAP = "  "  # two spaces between a value and its comment, as the cell files are written
_INSERT_HERE = "\x00"  # where add_after_last_value puts its line: TOML allows no NUL, so no document holds one


def matrix(rows: Iterable[Sequence[float]], decimals: int | None = MATRIX_DECIMALS, *, multiline: bool = True,
           comment: str | None = None) -> Array:
    """``rows`` (a 4x4 transform, an (n, 3) point list, ...) as an array of arrays of numbers printed with
    ``decimals`` decimals (None: each number exactly as it is, an integer as an integer): one row per line
    (``multiline``), or all on one line. ``comment`` goes after the opening bracket (``T_b_f = [  # REPLACE``;
    multi-line only)."""
    out = tomlkit.array()
    lines = [numbers(row, decimals) for row in rows]
    if not multiline:
        out.extend(lines)
        return out
    if comment:
        out.add_line(comment=comment.removeprefix("#").strip(), indent=COMMENT_GAP, newline=False)
    for line in lines:
        out.add_line(line, indent=ROW_INDENT)
    out.add_line(indent="")
    return out


def numbers(values: Iterable[float], decimals: int | None) -> Array:
    """A list of numbers on one line, each printed with ``decimals`` decimals (None: exactly as it is)."""
    out = tomlkit.array()
    out.extend(number(v, decimals) for v in values)
    return out


def number(value: float, decimals: int | None) -> Item:
    """A float printed with ``decimals`` decimals (``5.0`` -> ``5.000000`` with 6; None: as Python prints it,
    which reads back to the same float, and an integer stays one)."""
    return tomlkit.item(value) if decimals is None else tomlkit.value(f"{float(value):.{decimals}f}")


def inline_table(values: Mapping[str, Any]) -> InlineTable:
    """``values`` as an inline table, spaced inside its braces: ``{ a = 1, b = [2.0, 3.0] }`` (``{}`` if empty)."""
    out = tomlkit.inline_table()
    if values:
        out.add(tomlkit.ws(" "))
        out.update(values)
        out.add(tomlkit.ws(" "))
    return out


def commented(item: Item, comment: str) -> Item:
    """``item`` (a value or a table) with ``comment`` after it on its line; returns ``item``."""
    item.comment(comment)
    item.trivia.comment_ws = COMMENT_GAP
    return item


def opening_comment(value: object) -> str | None:
    """The comment after a multi-line array's opening bracket (``T_b_f = [  # REPLACE`` -> ``REPLACE``), if any."""
    if not isinstance(value, Array):
        return None
    first, newline, _ = value.as_string().partition("\n")
    rest = first.strip().removeprefix("[").strip()
    return rest.removeprefix("#").strip() if newline and rest.startswith("#") else None


def add_after_last_value(doc: TOMLDocument, table: Table | InlineTable | MutableMapping[str, Any], key: str,
                         item: Item) -> TOMLDocument:
    """Add ``key = item`` to ``table`` (a table of ``doc``) right after its last value: above the comments that
    end the table (they introduce the next one) and above its sub-tables. Returns the document that holds it.

    tomlkit has no public way to put a key at a place in a table (only at its end, below those comments), so the
    line goes into ``doc``'s text right after the last value's line and the text is parsed anew: the document
    returned is a new one, and ``doc`` and its items are not to be used after. Where no place is to be kept
    (``table`` an inline table, or with no value yet; ``key`` already in it) the key is set in ``table`` and
    ``doc`` itself is returned."""
    last = _last_value(table) if isinstance(table, Table) and key not in table else None
    if last is None or isinstance(item, Table | AoT):
        table[key] = item
        return doc
    trail = last.trivia.trail
    last.trivia.trail = trail + _INSERT_HERE
    try:
        text = doc.as_string()
    finally:
        last.trivia.trail = trail
    if text.count(_INSERT_HERE) != 1:
        raise ValueError(f"cannot add {key!r}: the table given is not a table of the document")
    line = tomlkit.document()
    line[key] = item
    added = last.trivia.indent.rpartition("\n")[2] + line.as_string()
    if not trail.endswith("\n"):  # the last value ends the file without a newline
        added = "\n" + added
    return tomlkit.parse(text.replace(_INSERT_HERE, added))


def replace_section(doc: MutableMapping[str, Any], name: str, new: Table | AoT) -> None:
    """Put ``new`` (a table or an array of tables) where ``doc[name]`` was, or at the end of ``doc``; the comment
    lines directly above the table that follows the old section stay there."""
    if name not in doc:
        doc[name] = new
        return
    followed = _followed_by_a_table(doc, name)
    above_next = _comments_at_end(doc[name]) if followed else []
    doc[name] = new
    end = new.body[-1] if isinstance(new, AoT) and new.body else new  # renders last: its body after its sub-tables
    if followed and isinstance(end, Table):
        body = end.value.body
        if not (body and body[-1][0] is None and isinstance(body[-1][1], Whitespace)):
            end.add(tomlkit.nl())  # a blank line before the next table (and the comments right above it)
        for comment in above_next:
            end.add(comment)


def _last_value(table: Table) -> Item | None:
    """The last value of ``table`` written as ``key = value`` (not a sub-table, not an array of tables)."""
    values = [value for key, value in table.value.body if key is not None and not isinstance(value, Table | AoT)]
    return values[-1] if values else None


def _last_table(item: object) -> Table | None:
    """The table whose body a document renders last inside ``item`` (its last sub-table, or last entry)."""
    if isinstance(item, AoT):
        return _last_table(item.body[-1]) if item.body else None
    if not isinstance(item, Table):
        return None
    body = item.value.body
    return _last_table(body[-1][1]) if body and isinstance(body[-1][1], Table | AoT) else item


def _comments_at_end(item: object) -> list[Comment]:
    """The comment lines that end ``item``'s text with no blank line after them."""
    table = _last_table(item)
    comments: list[Comment] = []
    for key, value in reversed(table.value.body if table is not None else []):
        if key is not None or not isinstance(value, Comment):
            break
        comments.insert(0, value)
    return comments


def _followed_by_a_table(doc: MutableMapping[str, Any], name: str) -> bool:
    body = getattr(doc, "body", [])
    at = [i for i, (key, _) in enumerate(body) if key is not None and key.key == name]
    return bool(at) and any(key is not None for key, _ in body[at[-1] + 1:])
