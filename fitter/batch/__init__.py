"""`duhem batch`: one validated model, FMU, report (and diagnosis) per device, on Dask.

Manifest
--------
A CSV file with one header line and one row per device:

``device`` (required)
    The device's name; it names the output directory ``OUTDIR/<device>/``, so it
    must be a safe directory name: letters, digits, ``-``, ``_`` and ``.``, not
    starting with ``.`` or ``-``, at most 100 characters, unique (also ignoring
    case), and not ``summary.csv``, ``summary.json`` or ``index.html``.
``recordings`` (required)
    The device's recording files, several separated by ``;`` (one experiment
    per file, e.g. one per rate, as ``duhem fit REC1.csv REC2.csv``).  A
    relative path is relative to the manifest's directory.
``time``, ``input``, ``output`` (optional)
    Column names or 0-based indices, as ``--time/--input/--output`` of
    ``duhem fit`` (defaults ``time``, ``u``, ``y``; an empty cell takes the
    default); ``time`` = ``none`` reads the file without a time column (the
    sample index is the time, ``--no-time``).
``input_unit``, ``output_unit`` (optional)
    Units of the input and output (e.g. ``V``, ``um``) when the column header
    does not carry one (a given unit replaces the header's); they go into the
    model and the FMU.

A bad manifest (a missing or unknown column, a missing recording file, an
empty or duplicate or unsafe device name) is a `BatchError` naming the
manifest, the row (as numbered in the file, header = line 1) and the value;
nothing is written.  A recording whose *content* is bad (non-numeric cell,
too few samples, ...) is not a manifest error: that device fails, and the
summary says why.

Per device (a task on a Dask worker, `process_device`)
------------------------------------------------------
fit (`fit_recordings`, ``kind``/``order``/``faithful_minor_loops``/``effects``/``held`` as ``duhem fit``)
-> ``model.json`` and ``fit.json`` (the fit summary); the FMU ``model.fmu`` (``backend``,
native by default); validation of the FMU against every recording with fmpy,
as ``duhem validate`` does (``validation.json``, ``validation.png``; NRMSE
over all samples against ``threshold``); the fit report ``report/``; with
``diagnose``, `fitter.diagnosis.diagnose` with the fitted model as its base
(``diagnosis.json``, ``diagnosis/``).  The worker reads no file and writes
none outside its own scratch directory: the client sends the recordings'
bytes and gets the output files back as bytes, so a cluster needs no shared
file system, and a worker that dies leaves nothing in OUTDIR.

The client writes each finished device as a whole: a temporary directory
beside ``OUTDIR/<device>`` renamed into place (`atomic_directory`), the last
file being ``done.json`` (status, the row of the summary, every output
file with its size, and the input hash).  The input hash is the SHA-256 of
the package version, `BATCH_FORMAT`, the options that change the outputs
(kind, order, backend, diagnose, threshold, faithful minor loops, effects, held parameters), the device's
column and unit choices, and each recording's name as written in the manifest and its bytes
(the recording's location on disk does not enter: a copied tree stays
current).  A re-run skips a device whose ``done.json`` has the same hash and
whose files are all present with their recorded sizes ("skipped: current").
A device that failed on its data (a `DuhemError`, ``ValueError``,
``OSError``) gets a directory with only ``done.json`` (status ``failed`` and
the one-line reason) and is skipped while its inputs stay the same
(``retry_failed`` runs it again).  A device whose worker died more often
than the scheduler allows (``distributed.scheduler.allowed-failures``,
default 3: the scheduler re-runs the task of a dead worker elsewhere), or
whose task raised an unexpected error ``RETRIES`` + 1 times, is reported as
failed in the summary and gets no directory, so the next run tries again.

Status: ``ok``; ``invalid`` (outputs written, but the FMU's NRMSE on some
recording exceeds the threshold, the exit-3 case of ``duhem validate``);
``failed`` (no outputs, the reason in the summary).

Summary (``OUTDIR/summary.csv``, ``summary.json``, ``index.html``)
---------------------------------------------------------------------
One row per device of the manifest: status and reason, what was done this
run (``action``), kind and order, the worst NRMSE of the FMU over the
device's recordings, the validation verdict, the fitted parameters with
their standard errors, the diagnosis verdict and the effects found, and
``outliers``.

Outlier rule (`flag_outliers`): the fitted parameters are those of the fit
summary (the canonical form of the model, fitted in units normalised by each
device's own input and output ranges: they describe the loop's shape, not
the sensor gain).  Devices are compared within a group of the same kind and
order with at least `MIN_GROUP` members; for each parameter, the robust
z-score is z = 0.6745 (p - median) / MAD (MAD = median absolute deviation
from the median; Iglewicz & Hoaglin), and a device is flagged for that
parameter when |z| > `OUTLIER_Z` (3.5).  A parameter whose MAD is 0 (all
devices but a few equal) uses 1.2533 x the mean absolute deviation instead;
when that is 0 too, nothing is flagged for it.  The canonical parameters are well determined at order 1;
at higher orders those of similar loops can differ by orders of magnitude (companion form), so a flag
there says that the models differ more than the devices need to (``--order`` puts a batch in one class).

Dask (`run_batch`)
------------------
A ``distributed.LocalCluster`` of ``workers`` processes with one thread
each (default: one per core), or an existing cluster (``scheduler`` address
or ``client``).  Tasks are submitted with ``retries=RETRIES`` and
collected as they finish; one device's failure never stops the batch.
Progress: a rich progress bar on stderr when it is a terminal, and the
dashboard link when there is one.  Devices that are current are never
submitted; when every device is current no cluster is started.  At the end,
leftover temporary entries in OUTDIR (``.tmp-*``, ``.old-*``: from a client
that was killed) are removed; one writer at a time may write into an OUTDIR
(`fitter.core.files.output_lock` of OUTDIR: a second batch, or a report
written there, waits a bounded time, then fails naming the first).
"""

from fitter.batch.config import BATCH_FORMAT, DASK_MISSING, MIN_GROUP, OUTLIER_Z, RETRIES, BatchError
from fitter.batch.device import DeviceTask, process_device
from fitter.batch.manifest import BatchOptions, DeviceSpec, input_hash, read_manifest
from fitter.batch.scheduling import run_batch
from fitter.batch.summary import BatchReport, flag_outliers

__all__ = [
    "BatchError",
    "BatchOptions",
    "DeviceSpec",
    "DeviceTask",
    "BatchReport",
    "read_manifest",
    "run_batch",
    "process_device",
    "flag_outliers",
    "input_hash",
    "BATCH_FORMAT",
    "OUTLIER_Z",
    "MIN_GROUP",
    "RETRIES",
    "DASK_MISSING",
]
