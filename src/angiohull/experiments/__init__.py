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

import importlib
from typing import Any

# Each name is imported from its module when first used (PEP 562): reading a configuration (the
# command line's `experiment --help` lists the shipped ones) need not import the runner, the
# report and matplotlib, about 1.5 s.
_HOME = {
    "ConfigError": "config", "ExperimentConfig": "config", "load_config": "config", "shipped_config_names": "config",
    "expand_cases": "cases", "row_columns": "cases", "run_case": "cases",
    "RunSummary": "runner", "run_experiment": "runner", "load_run": "runner",
    "build_report": "report", "PAPER_RESULTS": "paper",
}

__all__ = list(_HOME)


def __getattr__(name: str) -> Any:
    if name not in _HOME:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f".{_HOME[name]}", __name__), name)
    globals()[name] = value  # found once
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_HOME))
