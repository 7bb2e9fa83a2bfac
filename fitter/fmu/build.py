"""FMU generator: a model (or a saved model JSON) in, an FMI 2.0 (or 3.0) Co-Simulation FMU out.

`build_fmu(model_or_json_path, out_path, backend=...)` dispatches to a
backend and writes the FMU atomically (`fitter.core.files.atomic_file`: a
temporary name beside `out_path`, renamed into place; the usual mode
0o666 & ~umask whichever backend wrote it), so a failed build never leaves a
partial file.  The command lines are ``duhem export`` and the script
``build_fmu.py``.

The ``native`` backend is `fitter.fmu.native.build_native_fmu` (C, the host
needs no Python); it alone exports FMI 3.0 (``fmi_version=3``).

The ``python`` backend (pythonfmu)
----------------------------------
The FMU's ``resources/`` holds

* ``duhem_slave_<code>.py``: the slave class of ``fmu_src/duhem_slave.py``,
* ``duhem_core_<code>/``: a copy of the ``fitter/core`` package, the one
  simulation kernel (numpy only, relative imports only),
* ``model.json``: the model, as `fitter.core.save_model` writes it,
* ``duhem_fmu.json``: the kernel package name, the model file name and the
  variable table of `fitter.fmu.variables.model_variables`,
* ``pythonfmu/``: the pythonfmu runtime that pythonfmu embeds.

``<code>`` is a hash of the slave and kernel sources.  pythonfmu's binary
imports the slave module by name into the host's single Python interpreter, so
FMUs built by different versions of this project would otherwise share the
first-loaded slave and kernel; with the hash in the names each version brings
its own, while FMUs of one version share the modules (each instance still reads
its own model from its own resources).  The host needs only Python with numpy.

What pythonfmu needs, and how it is given:

* its binary finds the slave class with the regular expression
  ``^class (\\w+)\\(\\s*Fmi2Slave\\s*\\)\\s*:`` in ``resources/<module>.py``;
  ``fmu_src/duhem_slave.py`` keeps that literal class statement;
* `FmuBuilder.build_FMU` imports the script and instantiates the class once
  (it inserts directories into ``sys.path`` and adds modules to
  ``sys.modules``); the build runs with the slave copied into a staging
  directory next to the resources it reads, and ``sys.path`` and the modules it
  imported are restored afterwards;
* pythonfmu's own modelDescription omits ``InitialUnknowns``; the built zip is
  rewritten with the complete modelDescription of
  `fitter.fmu.model_description.model_description_xml`.

The compensator (``inverse=True``, ``duhem export --inverse``): the same
slave in its compensator mode (``"inverse": true`` in ``duhem_fmu.json``, the
kernel's `fitter.core.inverse.Compensator`), model identifier
``duhem_compensator``, the interface of
`fitter.fmu.variables.compensator_variables`.  The model it carries is
the plant the compensator inverts (``measurement="drop"`` has removed the
measurement effects; "refuse", the default, refuses a model that has them).
The native backend builds it from ``fmu_src/native/inverse_model.c``.

The GUID is deterministic: a UUID5 of the backend, the code hash and the
model JSON, so the same model exported by the same code gets the same GUID.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import shutil
import sys
import uuid
import zipfile
from pathlib import Path

import fitter.core
import fmu_src
from fitter.core import load_model, save_model
from fitter.core.errors import DuhemError
from fitter.core.files import atomic_file, scratch_directory, write_json
from fitter.core.inverse import Compensator
from fitter.fmu.model_description import FMI_VERSIONS, converges, model_description_xml, package_version
from fitter.fmu.variables import compensator_variables, model_variables, reference_start
from fitter.fmu.native import build_native_compensator, build_native_fmu

__all__ = [
    "build_fmu",
    "FmuBuildError",
    "MODEL_IDENTIFIER",
    "COMPENSATOR_IDENTIFIER",
    "BACKENDS",
    "FMI_VERSIONS",
    "PYTHON_HOST_NEEDS",
]

MODEL_IDENTIFIER = "semilinear_duhem"
COMPENSATOR_IDENTIFIER = "duhem_compensator"
BACKENDS = ("python", "native")
_SLAVE_SOURCE = Path(fmu_src.__file__).resolve().parent / "duhem_slave.py"
_CORE_DIR = Path(fitter.core.__file__).resolve().parent
_NOT_SHIPPED = ("compiled.py",)
"""Kernel modules left out of the FMUs: the optimiser's compiled scan (numba, `fitter.core.compiled`)."""
_GUID_NAMESPACE = uuid.UUID("5b0c1f4e-3a9d-4c1e-9a57-2f3f8d6f1e21")
_PYTHON_OPTIONS = ("model_name", "description", "version", "author")

PYTHON_HOST_NEEDS = (
    "note: a python-backend FMU runs only in a host that can load libpython3 and import numpy and "
    "pythonfmu (this venv's Python on its path): fmusim, Simulink, Dymola and the FMI Compliance "
    "Checker need --backend native"
)
"""What a host needs for a python-backend FMU, in one line (printed by `duhem export`/`fit`/`diagnose`)."""


class FmuBuildError(DuhemError, RuntimeError):
    """The FMU could not be built; the message says why."""


def _load(model_or_json_path):
    if isinstance(model_or_json_path, (str, os.PathLike)):
        return load_model(model_or_json_path)
    if getattr(model_or_json_path, "kind", None) not in ("ri", "rd"):
        raise TypeError(f"expected a model or a model JSON path, got {type(model_or_json_path).__name__}")
    return model_or_json_path


def _code_hash() -> str:
    """Hash of the slave and kernel sources (names the modules shipped in the FMU)."""
    h = hashlib.sha256(_SLAVE_SOURCE.read_bytes())
    for path in sorted(p for p in _CORE_DIR.rglob("*.py") if p.name not in _NOT_SHIPPED):
        h.update(path.relative_to(_CORE_DIR).as_posix().encode())
        h.update(path.read_bytes())
    return h.hexdigest()[:12]


def _guid(model_json: str, code: str, backend: str) -> str:
    """Deterministic GUID: same model, same code, same backend -> same GUID."""
    return "{" + str(uuid.uuid5(_GUID_NAMESPACE, f"{backend}:{code}:{model_json}")) + "}"


def _stage(model, staging: Path, code: str, inverse_start: float | None = None) -> tuple[Path, list[Path]]:
    """Write the slave script and the resources pythonfmu copies into the FMU (the compensator's when
    `inverse_start`, the start value of y_ref, is given)."""
    kernel = f"duhem_core_{code}"
    script = staging / f"duhem_slave_{code}.py"
    shutil.copyfile(_SLAVE_SOURCE, script)
    shutil.copytree(_CORE_DIR, staging / kernel, ignore=shutil.ignore_patterns("__pycache__", *_NOT_SHIPPED))
    save_model(model, staging / "model.json")
    variables = model_variables(model) if inverse_start is None else compensator_variables(model, inverse_start)
    write_json(
        staging / "duhem_fmu.json",
        {
            "model_identifier": MODEL_IDENTIFIER if inverse_start is None else COMPENSATOR_IDENTIFIER,
            "kernel_package": kernel,
            "model_file": "model.json",
            "inverse": inverse_start is not None,
            "variables": [v.to_json() for v in variables],
        },
        indent=1,
    )
    return script, [staging / kernel, staging / "model.json", staging / "duhem_fmu.json"]


@contextlib.contextmanager
def _isolated_imports(code: str):
    """Undo pythonfmu's changes to sys.path and its imports of the staged modules."""
    saved_path = list(sys.path)
    try:
        yield
    finally:
        sys.path[:] = saved_path
        for name in [m for m in sys.modules if m.endswith(code) or f"{code}." in m]:
            del sys.modules[name]


def _rewrite_zip(built: Path, target: Path, xml: str, identifier: str = MODEL_IDENTIFIER) -> None:
    """Copy the pythonfmu zip to `target`, with our modelDescription.xml."""
    with zipfile.ZipFile(built) as src, zipfile.ZipFile(target, "w", compression=zipfile.ZIP_DEFLATED) as dst:
        for item in src.infolist():
            if item.filename != "modelDescription.xml":
                dst.writestr(item.filename, src.read(item.filename))
        dst.writestr("modelDescription.xml", xml)
        binaries = [n for n in src.namelist() if n.startswith("binaries/")]
    if not any(Path(n).stem == identifier for n in binaries):
        raise FmuBuildError(f"pythonfmu named the binaries {binaries}, not {identifier}.*")


def _build_python(model, out_path: Path, inverse_start: float | None = None, **opts) -> None:
    from pythonfmu import __version__ as pythonfmu_version
    from pythonfmu.builder import FmuBuilder

    code = _code_hash()
    with scratch_directory("duhem_fmu") as tmp:
        staging = Path(tmp) / "staging"
        staging.mkdir()
        script, project_files = _stage(model, staging, code, inverse_start)
        model_json = (staging / "model.json").read_text(encoding="utf-8")
        with _isolated_imports(code):
            built = FmuBuilder.build_FMU(script, dest=Path(tmp) / "pythonfmu.fmu", project_files=project_files)
        identifier = MODEL_IDENTIFIER if inverse_start is None else COMPENSATOR_IDENTIFIER
        xml = model_description_xml(
            model,
            model_identifier=identifier,
            guid=_guid(model_json, code, "python" if inverse_start is None else "python:inverse"),
            backend="python",
            generation_tool=f"semilinear-duhem {package_version()} (pythonfmu {pythonfmu_version})",
            inverse_start=inverse_start,
            **opts,
        )
        _rewrite_zip(Path(built), out_path, xml, identifier)


def build_fmu(
    model_or_json_path,
    out_path: str | os.PathLike,
    *,
    backend: str = "python",
    allow_unstable: bool = False,
    fmi_version: int = 2,
    inverse: bool = False,
    measurement: str = "refuse",
    **opts,
) -> str:
    """Build an FMI 2.0 or 3.0 Co-Simulation FMU of a model; return the FMU's absolute path.

    Parameters
    ----------
    model_or_json_path : model or path
        A `RateIndependentModel`/`RateDependentModel`, or a model JSON file.
    out_path : path
        The FMU to write (replaced atomically).
    backend : {"python", "native"}
        ``python``: pythonfmu, needs Python with numpy in the host process.
        ``native``: C shared library (`fitter.fmu.native`).
    allow_unstable : bool
        Export a model whose fit recorded a violated convergence condition
        (``fit_info["convergence"]["satisfied"]`` false); the FMU's description
        then carries a warning.  Without it such a model is refused.
    fmi_version : {2, 3}
        The FMI version; 3 needs the native backend.
    inverse : bool
        Export the model's feedforward compensator (`fitter.core.inverse.Compensator`: input y_ref,
        output u) instead of the model.  The model needs an ``input_range`` (the inputs searched).
    measurement : {"refuse", "drop", "invert"}
        With `inverse`: what to do with the model's measurement effects (`fitter.core.inverse`).
    **opts
        Python backend: ``model_name``, ``description``, ``version`` (default:
        the version of semilinear-duhem that exports), ``author``
        (modelDescription attributes).  Native backend: passed on.

    Raises
    ------
    ValueError
        Unknown backend or FMI version.
    TypeError
        Unknown option of the python backend; not a model.
    InverseError
        `inverse` and the model has no input range, or measurement effects with measurement="refuse".
    FmuBuildError
        The backend failed, the model is unstable and `allow_unstable` is false, or FMI 3.0
        was asked of the python backend.
    """
    if backend not in BACKENDS:
        raise ValueError(f"unknown FMU backend {backend!r} (expected one of {', '.join(BACKENDS)})")
    if fmi_version not in FMI_VERSIONS:
        raise ValueError(f"unknown FMI version {fmi_version!r} (expected 2 or 3)")
    if fmi_version == 3 and backend != "native":
        raise FmuBuildError("FMI 3.0 export needs --backend native (pythonfmu writes FMI 2.0 only)")
    if backend == "python":
        unknown = sorted(set(opts) - set(_PYTHON_OPTIONS))
        if unknown:
            raise TypeError(
                f"unknown option(s) for the python backend: {', '.join(unknown)} (known: {', '.join(_PYTHON_OPTIONS)})"
            )
    model = _load(model_or_json_path)
    if not converges(model) and not allow_unstable:
        raise FmuBuildError(
            "the model's convergence condition is violated (fit_info.convergence: "
            f"{model.fit_info['convergence'].get('quantity')} = "
            f"{model.fit_info['convergence'].get('value')}, raw-input spectral radius "
            f"{model.fit_info['convergence'].get('rho_raw_input_per_recording')}): a wrong initial "
            "state need not die out; not exported (allow_unstable / --allow-unstable exports it "
            "with a warning in its description)"
        )
    inverse_start = None
    if inverse:
        model = Compensator(model, measurement=measurement).plant  # checks the input range and the effects
        inverse_start = reference_start(model)
    out = Path(out_path).resolve()
    with atomic_file(out) as tmp:
        if backend == "python":
            _build_python(model, tmp, inverse_start, **opts)
        elif inverse:
            build_native_compensator(model, str(tmp), fmi_version=fmi_version, **opts)
        else:
            build_native_fmu(model, str(tmp), fmi_version=fmi_version, **opts)
    return str(out)
