"""A model JSON and the FMU built from it, published and read as one pair.

`duhem fit -o model.json --fmu model.fmu` writes both through
`fitter.core.files.atomic_pair`: the JSON records the FMU it was written with
(``fit_info["fmu"] = {"file": path relative to the JSON, "sha256": digest}``)
and is renamed last.  Every command that reads a model JSON
(`check_fmu_pair`) first finishes or undoes an interrupted publication
(`fitter.core.files.recover_pair`), then says when the FMU beside the JSON is
not the one written with it (re-exported or replaced since: a note, not an
error, since exporting a model again is legitimate).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

from fitter.core.files import file_digest, recover_pair

__all__ = ["check_fmu_pair", "recorded_fmu_digest", "with_fmu_record"]


def with_fmu_record(model, fmu_path: str | os.PathLike, built: str | os.PathLike, json_path: str | os.PathLike):
    """`model` with ``fit_info["fmu"]``: the FMU's final path relative to the JSON, and the digest of `built`."""
    rel = os.path.relpath(Path(fmu_path).resolve(), Path(json_path).resolve().parent)
    return model.replace(fit_info={**model.fit_info, "fmu": {"file": rel, "sha256": file_digest(built)}})


def _record(model_or_info) -> dict | None:
    info = model_or_info.get("fit_info") if isinstance(model_or_info, dict) else model_or_info.fit_info
    rec = (info or {}).get("fmu")
    return rec if isinstance(rec, dict) and isinstance(rec.get("file"), str) else None


def recorded_fmu_digest(json_path: Path) -> str | None:
    """The FMU digest a model JSON records (None when it records none or cannot be read)."""
    try:
        rec = _record(json.loads(Path(json_path).read_text(encoding="utf-8")))
    except (OSError, ValueError):
        return None
    return rec.get("sha256") if rec else None


def check_fmu_pair(json_path: str | os.PathLike, model) -> str | None:
    """Recover an interrupted publication of the pair, then a note when the FMU beside the JSON differs
    from the one recorded (None: no FMU recorded, none there, or the pair matches)."""
    rec = _record(model)
    if rec is None:
        return None
    fmu = Path(json_path).parent / rec["file"]
    recover_pair(json_path, fmu, recorded_fmu_digest)
    if not fmu.is_file() or file_digest(fmu) == rec.get("sha256"):
        return None
    return (
        f"{fmu} is not the FMU that 'duhem fit' wrote with {json_path} (exported again or replaced "
        f"since); the model in {json_path} is used"
    )
