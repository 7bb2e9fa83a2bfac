"""Reading the chosen columns of a CSV recording: the file format, the choice of columns and the unit rule.

File format
-----------
A text file with one header line, then one row per sample; the delimiter is a
comma (a tab or semicolon is accepted when the header has no comma).  Blank
lines and comment lines starting with '#' (before the header or among the
data rows) are skipped; a UTF-8 byte-order mark is ignored.  A first row of
numbers is refused (the header is needed); a number with a decimal comma is
refused with a hint (write decimal points, or separate the columns by ';').  Only the three chosen
columns must be numeric.  The file is read a block of lines at a time: besides
the chosen columns (as float arrays) the reader holds about one block.

Choosing columns
----------------
A column is chosen by its header name, by its index (an ``int`` or a string
of digits that is not itself a header name; 0-based), or by the *base name*
left after removing a unit suffix (``voltage`` selects ``voltage_V``).  An
exact match wins over a base-name match, which wins over a case-insensitive
match; more than one candidate at the same level is an error.

Unit rule
---------
``name [unit]`` and ``name (unit)`` always give a unit.  ``name_unit`` gives
one only when the part after an underscore is *clearly* a unit: an optional SI
prefix, a known unit symbol (``m s g V A W J N Pa bar Hz C F H Ohm K degC rad
deg T S Wb mol cd L l percent``) and an optional integer exponent, possibly
joined by ``_per_`` (``uC_per_cm2`` -> ``uC/cm2``).  The longest such suffix
is taken: ``x_increasing_mm_per_s`` -> name ``x_increasing``, unit ``mm/s``;
``u_min`` has no unit.  A time column in ``ms``, ``us`` or ``ns`` is converted
to seconds.

"""

from __future__ import annotations

import csv
import io
import os
import re
from typing import Iterator, Sequence

import numpy as np

from fitter.core.errors import DuhemError

__all__ = ["RecordingError", "read_table", "split_unit"]

_PREFIXES = ("da", "Y", "Z", "E", "P", "T", "G", "M", "k", "h", "d", "c", "m", "u", "µ", "n", "p", "f", "a", "")
_UNITS = (
    "m",
    "s",
    "g",
    "V",
    "A",
    "W",
    "J",
    "N",
    "Pa",
    "bar",
    "Hz",
    "C",
    "F",
    "H",
    "Ohm",
    "ohm",
    "K",
    "degC",
    "rad",
    "deg",
    "T",
    "S",
    "Wb",
    "mol",
    "cd",
    "L",
    "l",
    "percent",
)
_UNIT_TOKEN = re.compile("^(?:%s)(?:%s)-?[0-9]?$" % ("|".join(_PREFIXES), "|".join(_UNITS)))
_BRACKET = re.compile(r"^(.*?)\s*[\[(]\s*([^\])]+?)\s*[\])]\s*$")


class RecordingError(DuhemError):
    """A recording file or column that cannot be used; the message names file, column, line, value."""


def split_unit(header: str) -> tuple[str, str]:
    """Split a column header into (name, unit) by the module's unit rule; unit "" if none."""
    header = header.strip()
    m = _BRACKET.match(header)
    if m and m.group(1):
        return m.group(1), m.group(2)
    tokens = header.split("_")
    for k in range(1, len(tokens)):
        unit = _unit_expression(tokens[k:])
        if unit:
            return "_".join(tokens[:k]), unit
    return header, ""


def _unit_expression(tokens: list[str]) -> str:
    """``['uC', 'per', 'cm2']`` -> ``'uC/cm2'``; "" when the tokens are not clearly a unit."""
    if len(tokens) % 2 == 0:
        return ""
    units, joins = tokens[0::2], tokens[1::2]
    if not all(j == "per" for j in joins) or not all(_UNIT_TOKEN.match(t) for t in units):
        return ""
    return "/".join(units)


def _find_column(spec: str | int, header: list[str], path: str, role: str) -> int:
    """Index of the column `spec` (name, base name or 0-based index) in `header`."""
    available = ", ".join(repr(h) for h in header)
    if isinstance(spec, (int, np.integer)) or (isinstance(spec, str) and spec.isdigit() and spec not in header):
        i = int(spec)
        if not 0 <= i < len(header):
            raise RecordingError(
                f"{path}: {role} column index {i} out of range: the file has {len(header)} columns ({available})"
            )
        return i
    bases = [split_unit(h)[0] for h in header]
    for candidates in (
        [h == spec for h in header],
        [b == spec for b in bases],
        [h.lower() == spec.lower() or b.lower() == spec.lower() for h, b in zip(header, bases)],
    ):
        hits = [i for i, c in enumerate(candidates) if c]
        if len(hits) == 1:
            return hits[0]
        if len(hits) > 1:
            raise RecordingError(
                f"{path}: {role} column {spec!r} is ambiguous: it matches " + ", ".join(repr(header[i]) for i in hits)
            )
    hint = "; a file without time: time=None (duhem: --no-time) uses the sample index" if role == "time" else ""
    raise RecordingError(f"{path}: {role} column {spec!r} not found (available: {available}){hint}")


_BLOCK_CHARS = 1 << 20
"""Characters of a CSV file read at a time: the reader holds one block of text (and its lines) besides the
chosen columns as float arrays."""
_NOT_SIMPLE = '"\x0b\x0c\x1c\x1d\x1e\x85\u2028\u2029'
r"""A quote, or a line break of `str.splitlines` other than "\n" and "\r\n": such a block is read row by row."""


def _text_blocks(path: str) -> Iterator[str]:
    r"""The file's text (UTF-8, a byte-order mark dropped) in blocks of whole lines.

    Every block but the last ends with "\n", so the blocks' `str.splitlines` are the lines of the
    whole text, in order ("\n" ends a line and begins no two-character line break).
    """
    try:
        with open(path, newline="", encoding="utf-8-sig") as fh:
            carry = ""
            while chunk := fh.read(_BLOCK_CHARS):
                carry += chunk
                cut = carry.rfind("\n") + 1
                if cut:
                    yield carry[:cut]
                    carry = carry[cut:]
            if carry:
                yield carry
    except FileNotFoundError:
        raise RecordingError(f"{path}: no such file") from None
    except IsADirectoryError:
        raise RecordingError(f"{path}: is a directory, not a CSV file") from None
    except UnicodeDecodeError:
        raise RecordingError(f"{path}: not a text (UTF-8) CSV file") from None


class _Table:
    """The chosen columns of a CSV file's data rows, gathered block by block as float arrays.

    Errors keep the order of a reader that first splits all rows, then finds the columns, then
    converts them column by column: a ragged row is raised where it is met; an unknown column, a
    non-number and a non-finite value are noted and raised by `columns` after the last row (time
    before input before output; in a column, its first non-number before its first non-finite value).
    """

    def __init__(self, path: str, header_line: str, specs: dict[str, str | int | None], rows_hint: int, line: int = 1):
        self.path = path
        self.delimiter = (
            "," if "," in header_line else "\t" if "\t" in header_line else ";" if ";" in header_line else ","
        )
        self.header = [h.strip() for h in _csv_rows(path, [header_line], self.delimiter, line)[0][1]]
        if all(_is_number(h) for h in self.header):
            raise RecordingError(
                f"{path}: line {line}: the first row {header_line.strip()[:60]!r} is numbers, not a "
                "header: a header line naming the columns is needed (e.g. time,u,y)"
            )
        self.cols: dict[str, int] = {}
        self.column_error: RecordingError | None = None
        try:
            for role, spec in specs.items():
                if spec is not None:
                    self.cols[role] = _find_column(spec, self.header, path, role)
        except RecordingError as exc:
            self.cols, self.column_error = {}, exc
        self.values = {role: _Column(rows_hint) for role in self.cols}
        self.lines: list[range | np.ndarray] = []
        self.errors: dict[str, dict[str, str]] = {"number": {}, "finite": {}}

    def add_block(self, text: str, first: int) -> int:
        """Add the data rows of `text` (whole lines, the first numbered `first`); return its line count."""
        added = self._add_simple(text, first)
        if added is None:
            lines = text.splitlines()
            self._add_rows(lines, first)
            added = len(lines)
        return added

    def _add_simple(self, text: str, first: int) -> int | None:
        r"""Add a block of simple lines at once and return their count; None (nothing added) otherwise.

        Simple: at least two columns, all chosen ones found, no quote, "\n" (or "\r\n") the only
        line break, exactly len(header) - 1 delimiters on every line, and `np.loadtxt` reads every
        chosen cell as a finite number.  Then csv's rows are the lines split at the delimiter, none is
        blank, and loadtxt's values are those of `float` (it accepts a subset of float's syntax,
        correctly rounded).
        """
        if len(self.header) < 2 or not self.cols or any(c in text for c in _NOT_SIMPLE):
            return None
        if "\r" in text:
            if text.count("\r") != text.count("\r\n"):
                return None
            text = text.replace("\r\n", "\n")
        if not text.endswith("\n"):
            text += "\n"
        code = np.frombuffer(text.encode("utf-8"), dtype=np.uint8)
        ends = np.flatnonzero(code == 10)
        per_line = np.diff(np.searchsorted(np.flatnonzero(code == ord(self.delimiter)), ends), prepend=0)
        del code
        if np.any(per_line != len(self.header) - 1):
            return None
        try:
            values = np.loadtxt(
                io.StringIO(text),
                delimiter=self.delimiter,
                usecols=list(self.cols.values()),
                comments=None,
                quotechar=None,
                dtype=float,
                ndmin=2,
            )
        except ValueError:
            return None
        if values.shape[0] != len(ends) or not np.isfinite(values).all():
            return None
        for j, role in enumerate(self.cols):
            self.values[role].extend(values[:, j])
        self.lines.append(range(first, first + len(ends)))
        return len(ends)

    def _add_rows(self, lines: list[str], first: int) -> None:
        """Add the data rows of `lines` one by one (csv), skipping blank rows; a ragged row is an error."""
        rows, numbers = [], []
        for number, row in _csv_rows(self.path, lines, self.delimiter, first):
            if not row or all(not c.strip() for c in row) or row[0].lstrip().startswith("#"):
                continue
            if len(row) != len(self.header):
                comma = (
                    " (decimal commas? write decimal points, or separate the columns by ';')"
                    if self.delimiter == "," and len(row) > len(self.header)
                    else ""
                )
                raise RecordingError(
                    f"{self.path}: line {number} has {len(row)} fields but the header has {len(self.header)}{comma}"
                )
            rows.append(row)
            numbers.append(number)
        follow = bool(numbers) and numbers[-1] - numbers[0] == len(numbers) - 1
        self.lines.append(range(numbers[0], numbers[-1] + 1) if follow else np.array(numbers, dtype=np.int64))
        for role, i in self.cols.items():
            self.values[role].extend(self._values(role, [r[i] for r in rows], numbers))

    def _values(self, role: str, cells: list[str], numbers: list[int]) -> np.ndarray:
        """`cells` as floats; the first non-number and non-finite value of the column are noted."""
        name = self.header[self.cols[role]]
        try:
            values = np.array(cells, dtype=float)
        except ValueError:
            if role not in self.errors["number"]:
                cell, line = next((c, k) for c, k in zip(cells, numbers) if not _is_number(c))
                what = (
                    "an empty cell"
                    if not cell.strip()
                    else f"{cell.strip()!r} is not a number"
                    + (
                        " (a decimal comma? write a decimal point: " + cell.strip().replace(",", ".") + ")"
                        if _is_number(cell.replace(",", "."))
                        else ""
                    )
                )
                self.errors["number"][role] = f"{self.path}: line {line}, column {name!r}: {what}"
            return np.empty(0)
        bad = np.flatnonzero(~np.isfinite(values))
        if bad.size and role not in self.errors["finite"]:
            k = bad[0]
            self.errors["finite"][role] = (
                f"{self.path}: line {numbers[k]}, column {name!r}: value "
                f"{cells[k].strip()!r} is not finite (NaN or infinity)"
            )
        return values

    def columns(self) -> tuple[dict[str, np.ndarray], Sequence[int]]:
        """The chosen columns by role and the data rows' line numbers; the noted error, if any."""
        pieces = [p for p in self.lines if len(p)]
        if not pieces:
            raise RecordingError(f"{self.path}: no data rows after the header")
        if self.column_error is not None:
            raise self.column_error
        for role in self.cols:
            for kind in ("number", "finite"):
                if role in self.errors[kind]:
                    raise RecordingError(self.errors[kind][role])
        if all(isinstance(p, range) for p in pieces) and all(a.stop == b.start for a, b in zip(pieces, pieces[1:])):
            numbers: Sequence[int] = range(pieces[0].start, pieces[-1].stop)  # no blank line: no array
        else:
            numbers = np.concatenate([np.asarray(p, dtype=np.int64) for p in pieces])
        return {role: column.array() for role, column in self.values.items()}, numbers


class _Column:
    """Floats appended block by block to one array that doubles when full.

    A large array's pages take memory only once written, so a generous first capacity (the
    reader's estimate of the row count) costs nothing; `array` returns the filled part, shrunk
    in place.
    """

    def __init__(self, capacity: int):
        self.data = np.empty(max(capacity, 1))
        self.size = 0

    def extend(self, values: np.ndarray) -> None:
        end = self.size + len(values)
        if end > len(self.data):
            grown = np.empty(max(end, 2 * len(self.data)))
            grown[: self.size] = self.data[: self.size]
            self.data = grown
        self.data[self.size : end] = values
        self.size = end

    def array(self) -> np.ndarray:
        self.data.resize(self.size, refcheck=False)
        return self.data


def _csv_rows(path: str, lines: list[str], delimiter: str, first: int) -> list[tuple[int, list[str]]]:
    """(line number, fields) of `lines` (the first numbered `first`) as csv reads them; a field over csv's size
    limit is a `RecordingError` naming its line."""
    reader = csv.reader(lines, delimiter=delimiter)
    rows = []
    try:
        for row in reader:
            rows.append((first + reader.line_num - 1, row))
    except csv.Error as exc:
        limit = csv.field_size_limit()
        what = (
            f"a field of more than {limit} characters (csv's field size limit): not a CSV recording, or a "
            'quote (") left open'
            if "field larger than field limit" in str(exc)
            else f"not CSV: {exc}"
        )
        raise RecordingError(f"{path}: line {first + reader.line_num - 1}: {what}") from None
    return rows


def _is_number(cell: str) -> bool:
    try:
        float(cell)
    except ValueError:
        return False
    return True


def read_table(path: str, specs: dict[str, str | int | None]) -> _Table:
    """The header (the first line that is neither blank nor a comment starting with '#', as instruments write
    before their data) and the data rows of the CSV file `path`, block by block."""
    blocks = _text_blocks(path)
    line = 1
    for text in blocks:
        lines = text.splitlines(keepends=True)
        k = next((i for i, s in enumerate(lines) if s.strip() and not s.lstrip().startswith("#")), None)
        if k is None:
            line += len(lines)
            continue
        rows_hint = int(1.25 * os.path.getsize(path) * len(lines) / len(text)) + 1024
        table = _Table(path, lines[k].splitlines()[0], specs, rows_hint, line + k)
        rest = "".join(lines[k + 1 :])
        line += k + 1
        line += table.add_block(rest, line) if rest else 0
        break
    else:
        raise RecordingError(f"{path}: empty file (no header line)")
    for text in blocks:
        line += table.add_block(text, line)
    return table
