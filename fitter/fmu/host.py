"""Check an FMU file, drive an exported FMU with fmpy, and validate its modelDescription (FMPy style).

`check_fmu_file` looks at every part of an FMU before fmpy touches it and
names the broken one (`FmuFileError`); `validate_fmu_file` is fmpy's
validation of the modelDescription; `simulate_fmu` loads the binary and runs
it.

`simulate_fmu` is the host that the FMU's input semantics are written for: at
every sample t_k it sets u(t_k), reads y(t_k), then steps to t_{k+1}.  With
that host the FMU reproduces `fitter.core.simulate` of the sampled input.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import tempfile
import zipfile
import zlib
from collections import deque
from ctypes import byref
from pathlib import Path
from typing import Mapping, MutableSequence
from xml.etree import ElementTree
from xml.parsers.expat import errors as expat_errors

import numpy as np

from fitter.core.errors import DuhemError, ModelFileError
from fitter.core.models import Model, model_from_json
from fitter.data.recordings import check_samples

_FMI2_FATAL = 4
_MODEL_MEMBER = "resources/model.json"
"""Where an FMU exported by duhem carries its model (`fitter.fmu.build`)."""

__all__ = ["simulate_fmu", "validate_fmu_file", "check_fmu_file", "collecting_callbacks", "FmuFileError", "FmuRunError"]


class FmuRunError(DuhemError, RuntimeError):
    """The FMU could not be loaded or driven; the message says why."""


class FmuFileError(DuhemError):
    """A broken FMU file; the message names the file and the broken part."""


def check_fmu_file(fmu_path: str | os.PathLike) -> Model:
    """Check every part of an FMU exported by duhem, before fmpy touches it; return the model it carries.

    In order: a zip archive; ``modelDescription.xml`` present, well-formed XML
    (the error by line and column), FMI 2.0 or 3.0, valid against that
    version's schema (fmpy's XSD) and with a Co-Simulation interface; the
    binary of this platform present (``binaries/<platform>/<modelIdentifier>``)
    and loadable; ``resources/model.json`` present, valid JSON and a valid model (the
    key, `fitter.core.models.model_from_json`).

    Raises
    ------
    FmuFileError
        One line: the file, the broken part (archive member, XML line, JSON key) and what is wrong.
    """
    path = str(fmu_path)
    if not Path(path).is_file():
        raise FmuFileError(f"{path}: {'is a directory' if Path(path).is_dir() else 'no such file'}, not an FMU")
    try:
        with zipfile.ZipFile(path) as z:
            names = set(z.namelist())
            version, identifier = _model_description(path, z, names)
            _check_loadable(path, z, _binary(path, names, version, identifier))
            return _stored_model(path, z, names)
    except zipfile.BadZipFile:
        raise FmuFileError(f"{path}: not an FMU (not a zip archive, or a damaged one)") from None


def _read(path: str, z: zipfile.ZipFile, member: str) -> bytes:
    try:
        return z.read(member)
    except (zipfile.BadZipFile, zlib.error, EOFError):
        raise FmuFileError(f"{path}: {member} is damaged in the archive (it cannot be unpacked)") from None


def _model_description(path: str, z: zipfile.ZipFile, names: set[str]) -> tuple[str, str]:
    """(fmiVersion, Co-Simulation modelIdentifier) of the FMU's modelDescription.xml, checked."""
    from fmpy import read_model_description

    if "modelDescription.xml" not in names:
        raise FmuFileError(f"{path}: not an FMU (the archive has no modelDescription.xml)")
    try:
        root = ElementTree.fromstring(_read(path, z, "modelDescription.xml"))
    except ElementTree.ParseError as exc:
        line, column = exc.position
        raise FmuFileError(
            f"{path}: modelDescription.xml is not well-formed XML: line {line}, column {column + 1}: "
            f"{expat_errors.messages.get(exc.code, 'syntax error')}"
        ) from None
    version = root.get("fmiVersion")
    if root.tag != "fmiModelDescription" or not version:
        raise FmuFileError(
            f"{path}: modelDescription.xml is not an FMI model description (root element "
            f"<{root.tag}>, fmiVersion {version!r})"
        )
    if version != "2.0" and not version.startswith("3."):
        raise FmuFileError(f"{path}: modelDescription.xml declares fmiVersion {version!r}: not an FMI 2.0 or 3.0 FMU")
    try:
        md = read_model_description(path, validate=True)
    except Exception as exc:  # fmpy raises ValidationError (its schema) or a plain Exception
        raise FmuFileError(
            f"{path}: modelDescription.xml does not follow the FMI {version} schema: {_schema_problem(exc)}"
        ) from None
    if md.coSimulation is None:
        raise FmuFileError(f"{path}: modelDescription.xml has no <CoSimulation> element: not a Co-Simulation FMU")
    return version, md.coSimulation.modelIdentifier


def _schema_problem(exc: Exception) -> str:
    """The first problem of fmpy's validation, as "line L: what" (libxml2's words for what)."""
    problems = getattr(exc, "problems", None) or [str(exc)]
    found = re.search(r"\(line (\d+), column \d+\): (.*)", problems[0])
    return f"line {found[1]}: {found[2]}" if found else " ".join(problems[0].split())


def _binary(path: str, names: set[str], version: str, identifier: str) -> str:
    """The archive member of this platform's binary (FMI 2.0: binaries/linux64, 3.0: binaries/x86_64-linux)."""
    import fmpy

    folder = fmpy.platform if version == "2.0" else fmpy.platform_tuple
    member = f"binaries/{folder}/{identifier}{fmpy.sharedLibraryExtension}"
    if member not in names:
        present = sorted({n.split("/")[1] for n in names if n.startswith("binaries/") and n.count("/") >= 2})
        raise FmuFileError(
            f"{path}: no binary for this platform ({member} is missing; binaries for: {', '.join(present) or 'none'})"
        )
    return member


_LOAD_PROBE = "import ctypes, sys\ntry:\n    ctypes.CDLL(sys.argv[1])\nexcept OSError as exc:\n    sys.exit(str(exc))"
"""What `_check_loadable`'s child process runs: load the library; an OSError's text on stderr, exit 1."""


def _check_loadable(path: str, z: zipfile.ZipFile, member: str) -> None:
    """Load the binary `member` (unpacked to a private directory) in a child process; the error names the member.
    A damaged binary can crash the loader (SIGSEGV, SIGBUS) rather than raise: in the child it ends the child
    only, and the message says so, where loaded here it ended the duhem process without a word."""
    with tempfile.TemporaryDirectory(prefix="duhem_fmu_check.") as tmp:
        library = Path(tmp) / Path(member).name
        library.write_bytes(_read(path, z, member))
        try:
            done = subprocess.run(
                [sys.executable, "-c", _LOAD_PROBE, str(library)], capture_output=True, text=True, timeout=120
            )
        except subprocess.TimeoutExpired:
            raise FmuFileError(
                f"{path}: loading the binary {member} did not end in 120 s: export the FMU again"
            ) from None
    if done.returncode < 0:
        raise FmuFileError(
            f"{path}: the binary {member} crashed the loader (signal {-done.returncode}): the file is damaged; "
            "export the FMU again"
        )
    if done.returncode != 0:
        reason = done.stderr.strip().replace(str(library), "").strip(": ") or "the loader gives no reason"
        raise FmuFileError(f"{path}: the binary {member} cannot be loaded on this machine ({reason})")


def _stored_model(path: str, z: zipfile.ZipFile, names: set[str]) -> Model:
    """The model in `_MODEL_MEMBER`; its absence, invalid JSON or a schema error names the member."""
    if _MODEL_MEMBER not in names:
        raise FmuFileError(f"{path}: no {_MODEL_MEMBER}: not an FMU exported by duhem (it carries its model there)")
    try:
        return model_from_json(_read(path, z, _MODEL_MEMBER), source=f"{path}: {_MODEL_MEMBER}")
    except ModelFileError as exc:
        raise FmuFileError(str(exc)) from None


def validate_fmu_file(fmu_path: str | os.PathLike) -> list[str]:
    """fmpy's findings on the FMU's modelDescription (empty: valid).

    Checks the XML schema, variable names, ModelStructure, start values,
    causality/variability combinations and units (`fmpy.validation.validate_fmu`).
    """
    from fmpy.validation import validate_fmu

    if not Path(fmu_path).is_file():
        raise FileNotFoundError(f"{fmu_path}: no such FMU file")
    return list(validate_fmu(str(fmu_path)))


def _check_input(t, u, fmu_path) -> tuple[np.ndarray, np.ndarray]:
    """t (the sample index when None) and u as float arrays, checked by `check_samples`."""
    u = np.asarray(u, dtype=float).ravel()
    t = np.arange(u.size, dtype=float) if t is None else np.asarray(t, dtype=float).ravel()
    t, u, _ = check_samples(t, u, source=f"input of {Path(fmu_path).name}", min_samples=1)
    return t, u


def _value_references(md, fmu_path) -> tuple[int, int]:
    """The value references of the model FMU's input u and output y; `FmuRunError` naming the file otherwise (a
    compensator, input y_ref and output u, said as such)."""
    refs = {v.name: v.valueReference for v in md.modelVariables}
    if "y_ref" in refs and "y" not in refs:
        raise FmuRunError(
            f"{fmu_path}: a compensator FMU (input y_ref, output u): this host drives model FMUs (input u, output "
            "y); simulate or validate the model's FMU (duhem export MODEL.json), and check the compensator in the "
            "simulator that runs it"
        )
    missing = [n for n in ("u", "y") if n not in refs]
    if missing:
        raise FmuRunError(f"{fmu_path}: the FMU has no variable(s) {', '.join(missing)}: not a duhem model FMU")
    return refs["u"], refs["y"]


def _parameter_references(md, values: Mapping[str, float], fmu_path) -> dict[int, float]:
    """{value reference: value} of the real parameters named in `values`; FmuRunError naming an unknown one."""
    params = {v.name: v.valueReference for v in md.modelVariables if v.causality == "parameter" and v.type == "Real"}
    unknown = [n for n in values if n not in params]
    if unknown:
        raise FmuRunError(f"{fmu_path}: no real parameter named {', '.join(unknown)}")
    return {params[n]: float(v) for n, v in values.items()}


def collecting_callbacks(messages: MutableSequence[str]):
    """fmpy FMI 2.0 callbacks whose logger appends "[STATUS] message" to `messages` (a list, or a
    ``deque(maxlen=k)`` that keeps the last k: with logging on, an FMU may log every call).

    Keep the returned object alive as long as the instance lives.  Instantiate
    with ``loggingOn=True``: pythonfmu FMUs pass even their fatal errors to the
    logger only when logging is on.
    """
    from fmpy.fmi2 import (
        fmi2CallbackAllocateMemoryTYPE,
        fmi2CallbackFreeMemoryTYPE,
        fmi2CallbackFunctions,
        fmi2CallbackLoggerTYPE,
    )
    from fmpy import calloc, free
    from fmpy.logging import addLoggerProxy

    labels = ["OK", "WARNING", "DISCARD", "ERROR", "FATAL", "PENDING"]

    def logger(component, instance_name, status, category, message):
        label = labels[status] if 0 <= status < len(labels) else str(status)
        messages.append(f"[{label}] {message.decode('utf-8', 'replace')}")

    callbacks = fmi2CallbackFunctions()
    callbacks.logger = fmi2CallbackLoggerTYPE(logger)
    callbacks.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
    callbacks.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
    addLoggerProxy(byref(callbacks))
    return callbacks


def _release(fmu, instantiated: bool) -> None:
    """Free the instance (or only the library when instantiation failed).

    Not called after fmi2Fatal: FMI 2.0 allows no further call then.  (A
    python FMU of this version survives one, `fmu_src/duhem_slave.py`; one
    exported before it, or another pythonfmu FMU, crashes on
    fmi2FreeInstance after a fatal error: pythonfmu's exception path has
    already released its Python objects.)
    """
    if instantiated:
        fmu.freeInstance()
    else:
        fmu.freeLibrary()


_GUID_REFUSED = re.compile(r'GUID "([^"]*)" does not match this FMU\'s "([^"]*)"')
"""The native binary's refusal of a GUID other than its own (fmi2Instantiate, `fmu_src/native/cosimulation.c`)."""


def _run_failure(fmu_path, exc: Exception, log: str, guid: str) -> str:
    """The message of a failed FMU run: a GUID refusal names both GUIDs, otherwise fmpy's error and the log's tail."""
    refused = _GUID_REFUSED.search(log)
    if refused:
        return (
            f"{fmu_path}: GUID mismatch: modelDescription.xml gives {guid}, the binary was built for "
            f"{refused[2]} (the archive mixes two exports, or was edited): export the FMU again"
        )
    return f"{fmu_path}: {exc}" + (f" FMU log: {log}" if log else "")


def simulate_fmu(fmu_path: str | os.PathLike, t, u, start: Mapping[str, float] | None = None) -> np.ndarray:
    """Output y at every sample of (t, u), from the FMU driven by fmpy's `FMU2Slave`.

    At each sample k: set u_k, read y_k, then ``doStep(t_k, t_{k+1} - t_k)``.
    `t` may be None for the sample index (rate-independent models ignore time).
    `start`: real parameters set by name before initialisation (for example ``{"x0[1]": 0.2}``, the start
    state: `fitter.fmu.variables.start_state_values`).
    Raises `FmuRunError` when the FMU fails (with fmpy's message) or has no parameter of a `start` name.
    """
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave

    t, u = _check_input(t, u, fmu_path)
    if not Path(fmu_path).is_file():
        raise FileNotFoundError(f"{fmu_path}: no such FMU file")
    md = read_model_description(str(fmu_path))
    if md.fmiVersion != "2.0":
        raise FmuRunError(
            f"{fmu_path}: an FMI {md.fmiVersion} FMU: this host drives FMI 2.0 FMUs (export for FMI 2.0 "
            f"to simulate or validate it here)"
        )
    if md.coSimulation is None:
        raise FmuRunError(f"{fmu_path}: not a Co-Simulation FMU")
    vr_u, vr_y = _value_references(md, fmu_path)
    vr_start = _parameter_references(md, start or {}, fmu_path)
    unzipdir = extract(str(fmu_path))
    fmu = FMU2Slave(
        guid=md.guid, unzipDirectory=unzipdir, modelIdentifier=md.coSimulation.modelIdentifier, instanceName="duhem"
    )
    y = np.empty(len(u))
    messages: deque[str] = deque(maxlen=3)  # the log's tail for an error message; not one entry per call
    callbacks = collecting_callbacks(messages)
    instantiated = fatal = False
    try:
        fmu.instantiate(callbacks=callbacks, loggingOn=True)
        instantiated = True
        fmu.setupExperiment(startTime=float(t[0]))
        if vr_start:
            fmu.setReal(list(vr_start), list(vr_start.values()))
        fmu.enterInitializationMode()
        fmu.setReal([vr_u], [float(u[0])])
        fmu.exitInitializationMode()
        for k in range(len(u)):
            fmu.setReal([vr_u], [float(u[k])])
            y[k] = fmu.getReal([vr_y])[0]
            if k + 1 < len(u):
                fmu.doStep(currentCommunicationPoint=float(t[k]), communicationStepSize=float(t[k + 1] - t[k]))
        fmu.terminate()
    except Exception as exc:  # fmpy raises FMICallException (and OSError on load)
        fatal = getattr(exc, "status", None) == _FMI2_FATAL
        raise FmuRunError(_run_failure(fmu_path, exc, "; ".join(messages), md.guid)) from exc
    finally:
        if not fatal:
            _release(fmu, instantiated)
        shutil.rmtree(unzipdir, ignore_errors=True)
    return y
