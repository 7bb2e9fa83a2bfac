"""The manifest (`read_manifest`: one `DeviceSpec` per row), the options (`BatchOptions`) and the input hash
that decides whether a device is done (the `fitter.batch` docstring).
"""

from __future__ import annotations

import csv
import dataclasses
import hashlib
import io
import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

from fitter.batch.config import BATCH_FORMAT, DEFAULT_COLUMNS, OPTIONAL, REQUIRED, RESERVED, SAFE_NAME, BatchError
from fitter.core.effects import REGISTRY
from fitter.core.errors import DuhemError
from fitter.fmu.model_description import package_version
from fitter.identification.effects_fit import check_held

# --------------------------------------------------------------------------- manifest


@dataclass(frozen=True)
class DeviceSpec:
    """One row of the manifest: the device, its recording files and column choices."""

    name: str
    row: int
    recordings: tuple[str, ...]  # as written in the manifest
    paths: tuple[str, ...]  # resolved
    time: str | None = "time"
    input: str = "u"
    output: str = "y"
    input_unit: str | None = None
    output_unit: str | None = None

    def columns(self) -> dict:
        return {
            "time": self.time,
            "input": self.input,
            "output": self.output,
            "input_unit": self.input_unit,
            "output_unit": self.output_unit,
        }


def read_manifest(path: str | os.PathLike) -> list[DeviceSpec]:
    """The devices of a manifest (module docstring); `BatchError` naming file, row and value."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8-sig")
    except FileNotFoundError:
        raise BatchError(f"{path}: no such manifest file") from None
    except IsADirectoryError:
        raise BatchError(f"{path}: is a directory, not a manifest file") from None
    except UnicodeDecodeError as exc:
        raise BatchError(f"{path}: not a UTF-8 text file ({exc.reason})") from None
    rows = [(i, r) for i, r in enumerate(csv.reader(io.StringIO(text)), start=1) if any(c.strip() for c in r)]
    if not rows:
        raise BatchError(f"{path}: empty manifest (expected a header line with columns {', '.join(REQUIRED)})")
    _, header = rows[0]
    header = [h.strip() for h in header]
    for h in header:
        if h not in REQUIRED + OPTIONAL:
            raise BatchError(f"{path}: line 1: unknown column {h!r} (allowed: {', '.join(REQUIRED + OPTIONAL)})")
    for h in REQUIRED:
        if h not in header:
            raise BatchError(
                f"{path}: line 1: no column {h!r} (columns: {', '.join(header)}; required: {', '.join(REQUIRED)})"
            )
    dup = next((h for i, h in enumerate(header) if h in header[:i]), None)
    if dup:
        raise BatchError(f"{path}: line 1: column {dup!r} appears twice")
    if len(rows) == 1:
        raise BatchError(f"{path}: no devices (only a header line)")
    base = path.resolve().parent
    devices, seen = [], {}
    for line, cells in rows[1:]:
        if len(cells) > len(header):
            raise BatchError(f"{path}: line {line}: {len(cells)} cells but the header has {len(header)} columns")
        cell = {h: (cells[i].strip() if i < len(cells) else "") for i, h in enumerate(header)}
        name = cell["device"]
        where = f"{path}: line {line}"
        if not name:
            raise BatchError(f"{where}: empty device name")
        if not SAFE_NAME.match(name) or name.lower() in RESERVED or name.endswith("."):
            raise BatchError(
                f"{where}: device name {name!r} is not a safe directory name (letters, digits, "
                "'-', '_', '.', not starting with '.' or '-', at most 100 characters, not "
                f"{', '.join(sorted(RESERVED))})"
            )
        if name.lower() in seen:
            raise BatchError(f"{where}: device {name!r} appears twice (also on line {seen[name.lower()]})")
        seen[name.lower()] = line
        recs = tuple(p.strip() for p in cell["recordings"].split(";") if p.strip())
        if not recs:
            raise BatchError(f"{where}: device {name!r} has no recording files")
        paths = []
        for rec in recs:
            p = Path(rec) if Path(rec).is_absolute() else base / rec
            if not p.is_file():
                raise BatchError(
                    f"{where}: device {name!r}: recording {rec!r}: "
                    f"{'is a directory' if p.is_dir() else 'no such file'} ({p})"
                )
            paths.append(str(p))
        if len(set(paths)) != len(paths):
            raise BatchError(f"{where}: device {name!r}: the same recording file is listed twice")
        cols = {k: cell.get(k) or DEFAULT_COLUMNS[k] for k in DEFAULT_COLUMNS}
        time_col = None if cols["time"].lower() == "none" else cols["time"]
        devices.append(
            DeviceSpec(
                name,
                line,
                recs,
                tuple(paths),
                time_col,
                cols["input"],
                cols["output"],
                cell.get("input_unit") or None,
                cell.get("output_unit") or None,
            )
        )
    return devices


# --------------------------------------------------------------------------- options and hash


@dataclass(frozen=True)
class BatchOptions:
    """What each device task does (every field enters the input hash)."""

    kind: str = "auto"
    order: int | None = None
    backend: str = "native"
    diagnose: bool = False
    threshold: float = 0.05
    faithful_minor_loops: bool = False
    effects: tuple[str, ...] = ()
    held: tuple[tuple[str, float], ...] = ()
    """Effect parameters held at known values, ("effect.parameter", value) pairs (``duhem fit --hold``)."""

    def __post_init__(self):
        object.__setattr__(self, "effects", tuple(self.effects))
        unknown = [e for e in self.effects if e not in REGISTRY]
        if unknown:
            raise BatchError(f"unknown effect {unknown[0]!r} (known: {', '.join(REGISTRY)})")
        try:
            held = check_held(dict(self.held), self.effects)
        except DuhemError as exc:
            raise BatchError(str(exc)) from None
        object.__setattr__(self, "held", tuple(sorted(held.items())))
        if self.kind not in ("auto", "ri", "rd"):
            raise BatchError(f"kind must be 'auto', 'ri' or 'rd', not {self.kind!r}")
        if self.backend not in ("native", "python"):
            raise BatchError(f"backend must be 'native' or 'python', not {self.backend!r}")
        if not self.threshold > 0:
            raise BatchError(f"the validation threshold must be positive, got {self.threshold}")


def input_hash(device: DeviceSpec, contents: Sequence[bytes], options: BatchOptions) -> str:
    """SHA-256 of everything a device's outputs depend on (module docstring)."""
    h = hashlib.sha256()
    head = {
        "package": package_version(),
        "format": BATCH_FORMAT,
        "options": dataclasses.asdict(options),
        "columns": device.columns(),
        "recordings": list(device.recordings),
    }
    h.update(json.dumps(head, sort_keys=True).encode())
    for data in contents:
        h.update(len(data).to_bytes(8, "little"))
        h.update(hashlib.sha256(data).digest())
    return h.hexdigest()
