"""``geocon validate``: the validation report the project keeps.

It scores (a) the synthetic scene families at several heights and codecs, clean and with injected
failures at three severities, (b) every real clip of a data folder against a person's
annotation (``assets/validation/annotations.csv``), and (c) with ``planted``, failures planted
into the annotated real-camera clips beside a clean re-encode of each, and summarises them in one
table (and the planted ones in a section of their own).

>>> from geocon_core.validation import ValidationPlan, run_validation      # doctest: +SKIP
>>> report = run_validation(ValidationPlan(), preset("paper"), "out", "cache")  # doctest: +SKIP

Modules: :mod:`.cases` (what to run), :mod:`.prepare` (rendering and cutting clips, cached),
:mod:`.runner` (scoring, resumable), :mod:`.results` (one row per case from its record),
:mod:`.metrics` (the table, with its intervals from :mod:`geocon_core.intervals`),
:mod:`.planted` (the planted failures' section), :mod:`.report` (the run and its written report),
:mod:`.footage` (the cache of annotated clips taken from public repositories).
"""

from .cases import (
    ANNOTATIONS_PATH,
    CODECS,
    HEIGHTS,
    LEVELS,
    PLANT_KINDS,
    PLANT_LEVELS,
    QUICK,
    SEVERITIES,
    Annotation,
    CaseSpec,
    ValidationPlan,
    missing_clips,
    plan_cases,
    planted_cases,
    read_annotations,
    real_clips,
    split_of,
    wrong_clips,
)
from .fit import FIT_TERMS, READINGS_FILE, FitCase, FitReport, FitRow, fit_cases, fit_markdown, fit_model, model_json
from .footage import DEFAULT_FOOTAGE, fill_footage, footage_status
from .metrics import MetricRow, compute_metrics, detected
from .peer import PEER_NAME, peer_keep_rate
from .planted import (
    PLANTED_COLUMNS,
    PLANTED_NOTE,
    PlantedCache,
    PlantedRow,
    PlantedSummary,
    ReencodeRow,
    cache_line,
    planted_cells,
    planted_rows,
    planted_summary,
    reencode_rows,
)
from .report import (
    INTERVALS_NOTE,
    REPORT_JSON,
    REPORT_MD,
    ValidationReport,
    format_value,
    metric_cells,
    run_validation,
    write_report,
)
from .results import CaseResult, case_result

__all__ = [
    "ANNOTATIONS_PATH",
    "CODECS",
    "HEIGHTS",
    "LEVELS",
    "PLANT_KINDS",
    "PLANT_LEVELS",
    "QUICK",
    "SEVERITIES",
    "Annotation",
    "CaseSpec",
    "ValidationPlan",
    "plan_cases",
    "planted_cases",
    "missing_clips",
    "wrong_clips",
    "split_of",
    "read_annotations",
    "real_clips",
    "MetricRow",
    "compute_metrics",
    "detected",
    "REPORT_JSON",
    "REPORT_MD",
    "INTERVALS_NOTE",
    "ValidationReport",
    "format_value",
    "metric_cells",
    "run_validation",
    "write_report",
    "CaseResult",
    "case_result",
    "FIT_TERMS",
    "READINGS_FILE",
    "FitCase",
    "FitReport",
    "FitRow",
    "fit_cases",
    "fit_markdown",
    "fit_model",
    "model_json",
    "DEFAULT_FOOTAGE",
    "fill_footage",
    "footage_status",
    "PEER_NAME",
    "peer_keep_rate",
    "PLANTED_COLUMNS",
    "PLANTED_NOTE",
    "cache_line",
    "planted_cells",
    "PlantedCache",
    "PlantedRow",
    "PlantedSummary",
    "ReencodeRow",
    "planted_rows",
    "planted_summary",
    "reencode_rows",
]
