"""Diagnosis of a model-data mismatch: locate it, name the physics left out, model it.

`diagnose` runs the procedure on one experiment (recordings on one clock) and
returns a `Diagnosis`; `synthetic_experiment` generates an experiment with one
effect concealed, from the project's own simulator; `chain_recordings` puts
files that each start their own clock back to back on one; `rich_progress` (from
`fitter.progress`) shows a diagnosis' progress as a bar.
"""

from fitter.diagnosis.procedure import diagnose
from fitter.diagnosis.experiment import DiagnoseError, JoinedExperiment, chain_recordings
from fitter.diagnosis.locate import locate_mismatch
from fitter.diagnosis.result import Diagnosis
from fitter.diagnosis.synthetic import synthetic_experiment
from fitter.progress import rich_progress

__all__ = [
    "DiagnoseError",
    "Diagnosis",
    "JoinedExperiment",
    "chain_recordings",
    "diagnose",
    "locate_mismatch",
    "rich_progress",
    "synthetic_experiment",
]
