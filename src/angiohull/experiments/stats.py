"""Summary statistics of the rows: mean, standard deviation, 95 % confidence interval, t-tests, bins.

NumPy and SciPy only. Undefined values (nan: an empty hull's Chamfer distance, a failed case) are
left out of every statistic; the count ``n`` says how many values entered it.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any, Sequence

import numpy as np
from scipy import stats as st

__all__ = ["Summary", "summarise", "TTest", "ttest", "group_by", "bin_edges", "spearman"]


@dataclass(frozen=True)
class Summary:
    """Mean, sample standard deviation (ddof = 1) and the two-sided 95 % t confidence interval of the mean."""

    n: int
    mean: float
    std: float
    ci_low: float
    ci_high: float

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def summarise(values: Sequence[float], confidence: float = 0.95) -> Summary:
    """:class:`Summary` of the finite values (mean ± t_{n-1} * std / sqrt(n))."""
    x = np.asarray(values, dtype=np.float64)
    x = x[np.isfinite(x)]
    n = int(x.size)
    if n == 0:
        return Summary(0, math.nan, math.nan, math.nan, math.nan)
    mean = float(x.mean())
    if n == 1:
        return Summary(1, mean, math.nan, math.nan, math.nan)
    std = float(x.std(ddof=1))
    half = float(st.t.ppf(0.5 + confidence / 2.0, n - 1)) * std / math.sqrt(n)
    return Summary(n, mean, std, mean - half, mean + half)


@dataclass(frozen=True)
class TTest:
    """Two-sided independent two-sample t-tests of two groups (Student's pooled variance and Welch's)."""

    group_a: str
    group_b: str
    n_a: int
    n_b: int
    mean_a: float
    mean_b: float
    t: float  # Student's statistic
    p_student: float
    p_welch: float

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def ttest(name_a: str, a: Sequence[float], name_b: str, b: Sequence[float]) -> TTest:
    """Student's and Welch's t-tests of the finite values of two groups (nan with fewer than 2 each)."""
    x = np.asarray(a, dtype=np.float64)
    y = np.asarray(b, dtype=np.float64)
    x, y = x[np.isfinite(x)], y[np.isfinite(y)]
    mean_a = float(x.mean()) if x.size else math.nan
    mean_b = float(y.mean()) if y.size else math.nan
    if x.size < 2 or y.size < 2:
        return TTest(name_a, name_b, int(x.size), int(y.size), mean_a, mean_b, math.nan, math.nan, math.nan)
    student = st.ttest_ind(x, y, equal_var=True)
    welch = st.ttest_ind(x, y, equal_var=False)
    return TTest(name_a, name_b, int(x.size), int(y.size), mean_a, mean_b, float(student.statistic),
                 float(student.pvalue), float(welch.pvalue))


def group_by(keys: Sequence[Any], values: Sequence[float]) -> dict[Any, list[float]]:
    """Values per key, keys in first-seen order."""
    out: dict[Any, list[float]] = {}
    for key, value in zip(keys, values):
        out.setdefault(key, []).append(value)
    return out


def bin_edges(x: Sequence[float], bins: int) -> np.ndarray:
    """``bins + 1`` equal-width edges spanning the finite values of ``x``."""
    values = np.asarray(x, dtype=np.float64)
    values = values[np.isfinite(values)]
    low, high = (float(values.min()), float(values.max())) if values.size else (0.0, 1.0)
    if high <= low:
        high = low + 1.0
    return np.linspace(low, high, bins + 1)


def spearman(x: Sequence[float], y: Sequence[float]) -> tuple[float, float, int]:
    """Spearman's rank correlation of the pairs where both are finite: (rho, p, n)."""
    a = np.asarray(x, dtype=np.float64)
    b = np.asarray(y, dtype=np.float64)
    ok = np.isfinite(a) & np.isfinite(b)
    n = int(ok.sum())
    if n < 3 or np.ptp(a[ok]) == 0 or np.ptp(b[ok]) == 0:
        return math.nan, math.nan, n
    result = st.spearmanr(a[ok], b[ok])
    return float(result.statistic), float(result.pvalue), n
