"""Parametric studies and folders of bags on ``dask.distributed`` (``clm study``, ``clm calibrate FOLDER``).

- :mod:`~clm_core.studies.spec`: the study file (YAML), checked; its cases;
- :mod:`~clm_core.studies.runner`: what a worker runs (one case, one bag) into one row;
- :mod:`~clm_core.studies.engine`: the dask engine (local cluster or remote scheduler);
- :mod:`~clm_core.studies.store`: the per-case result store and the results table;
- :mod:`~clm_core.studies.study`: the resumable run of a study or a bag folder.

Importing this package does not import dask: the engine imports it when it
starts (``clm --help`` stays fast). Format and examples: ``docs/studies.md``, ``examples/studies/``.
"""

from clm_core.studies.spec import Case, StudySpec, load_study, parse_study, simulate_argv
from clm_core.studies.study import Outcome, StudyInterrupted, calibrate_folder, run_study

__all__ = [
    "Case",
    "Outcome",
    "StudyInterrupted",
    "StudySpec",
    "calibrate_folder",
    "load_study",
    "parse_study",
    "run_study",
    "simulate_argv",
]
