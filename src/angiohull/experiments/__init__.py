"""The paper's experiments: configurations, a resumable runner (local processes or Dask), reports.

* :mod:`.config` — YAML configurations validated with pydantic (:func:`load_config`); the paper's
  studies ship as package data (:func:`shipped_config_names`);
* :mod:`.cases` — a configuration expanded into case records with derived seeds
  (:func:`expand_cases`), and one pure function from a record to a row (:func:`run_case`);
* :mod:`.rows` — the append-only, fsync'ed rows journal and atomic file writes;
* :mod:`.runner` — :func:`run_experiment`: local worker processes or a Dask cluster, progress,
  resume by case id;
* :mod:`.stats`, :mod:`.figures`, :mod:`.report` — tables (mean, std, 95 % CI), t-tests, figures
  and the Markdown report, recomputed from the rows; :mod:`.paper` holds the paper's published values.

Layer: above metrics and synthetic, below the CLI (docs/conventions.md).
"""

from __future__ import annotations

from .cases import expand_cases, row_columns, run_case
from .config import ConfigError, ExperimentConfig, load_config, shipped_config_names
from .paper import PAPER_RESULTS
from .report import build_report
from .runner import RunSummary, load_run, run_experiment

__all__ = [
    "ConfigError", "ExperimentConfig", "load_config", "shipped_config_names",
    "expand_cases", "row_columns", "run_case",
    "RunSummary", "run_experiment", "load_run",
    "build_report", "PAPER_RESULTS",
]
