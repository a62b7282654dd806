"""The statistics: rliable's (Agarwal et al., NeurIPS 2021) for the aggregates, their
stratified-bootstrap intervals, the performance profiles and the probability of
improvement; scipy's Welch t-test on seed means; Holm's step-down adjustment.

Nothing here re-implements rliable: every aggregate, interval and profile is a call
into ``rliable.metrics`` / ``rliable.library``. rliable's bootstraps draw their
indices from NumPy's *global* generator (``np.random.choice`` in
``StratifiedBootstrap.update_indices``), so each call below seeds it first: a result
depends on its inputs and ``seed`` only, not on what ran before it.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np
import scipy.stats
from rliable import library as rly
from rliable import metrics


def iqm(scores: np.ndarray) -> float:
    """Interquartile mean over all runs × tasks (``metrics.aggregate_iqm``)."""
    return float(metrics.aggregate_iqm(scores))


def optimality_gap(scores: np.ndarray, gamma: float = 1.0) -> float:
    """Optimality gap below ``gamma`` (1 = the oracle) (``metrics.aggregate_optimality_gap``)."""
    return float(metrics.aggregate_optimality_gap(scores, gamma))


def _aggregates(scores: np.ndarray) -> np.ndarray:
    return np.array([metrics.aggregate_iqm(scores), metrics.aggregate_optimality_gap(scores)])


@dataclass
class Estimate:
    """A point estimate with its percentile interval."""

    value: float
    low: float
    high: float

    def excludes(self, x: float) -> bool:
        return self.low > x or self.high < x


def aggregate_intervals(
    scores: dict[str, np.ndarray], *, reps: int, seed: int, level: float = 0.95
) -> dict[str, dict[str, Estimate]]:
    """IQM and optimality gap of each score matrix (runs × tasks) with rliable's stratified
    bootstrap (runs resampled within each task; percentile intervals)."""
    out = {}
    for name, m in scores.items():
        np.random.seed(seed)
        point, ci = rly.get_interval_estimates(
            {name: m}, _aggregates, reps=reps, confidence_interval_size=level, method="percentile"
        )
        p, c = point[name], ci[name]
        out[name] = {
            "iqm": Estimate(float(p[0]), float(c[0][0]), float(c[1][0])),
            "optimality_gap": Estimate(float(p[1]), float(c[0][1]), float(c[1][1])),
        }
    return out


def probability_of_improvement(x: np.ndarray, y: np.ndarray, *, reps: int, seed: int, level: float = 0.95) -> Estimate:
    """P(X > Y) averaged over tasks (``metrics.probability_of_improvement``: per task, the
    Mann–Whitney U of X's runs against Y's over n_x·n_y, ties counting ½), with rliable's
    stratified *independent* bootstrap (each arm's runs resampled within each task)."""
    np.random.seed(seed)
    point, ci = rly.get_interval_estimates(
        {"pair": [x, y]},
        metrics.probability_of_improvement,
        reps=reps,
        confidence_interval_size=level,
        method="percentile",
    )
    return Estimate(float(point["pair"]), float(np.ravel(ci["pair"][0])[0]), float(np.ravel(ci["pair"][1])[0]))


def performance_profiles(
    scores: dict[str, np.ndarray], taus: np.ndarray, *, reps: int, seed: int, level: float = 0.95
) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """Score distributions (fraction of run × task scores above τ) with stratified-bootstrap
    bands (``library.create_performance_profile``)."""
    np.random.seed(seed)
    return rly.create_performance_profile(scores, taus, reps=reps, confidence_interval_size=level)


@dataclass
class Welch:
    """Welch's unequal-variance t-test of two samples (here: seed means)."""

    n_x: int
    n_y: int
    diff: float  # mean(x) − mean(y)
    t: float
    df: float
    p: float  # two-sided
    low: float  # Welch interval of the difference
    high: float

    def as_dict(self) -> dict:
        return asdict(self)


def welch(x: np.ndarray, y: np.ndarray, level: float = 0.95) -> Welch:
    """``scipy.stats.ttest_ind(equal_var=False)``; undefined (NaN) with fewer than two
    values in an arm, or no spread in either (scipy would report t = ±inf, p = 0)."""
    x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    diff = float(x.mean() - y.mean()) if len(x) and len(y) else math.nan
    if len(x) < 2 or len(y) < 2 or (np.ptp(x) == 0 and np.ptp(y) == 0):
        return Welch(len(x), len(y), diff, math.nan, math.nan, math.nan, math.nan, math.nan)
    r = scipy.stats.ttest_ind(x, y, equal_var=False)
    ci = r.confidence_interval(level)
    return Welch(len(x), len(y), diff, float(r.statistic), float(r.df), float(r.pvalue), float(ci.low), float(ci.high))


def holm(pvalues: list[float]) -> list[float]:
    """Holm's step-down adjusted p-values, in the input's order; NaNs (undefined tests)
    stay NaN and do not count in the family."""
    idx = [i for i, p in enumerate(pvalues) if not math.isnan(p)]
    order = sorted(idx, key=lambda i: pvalues[i])
    m, out, running = len(order), [math.nan] * len(pvalues), 0.0
    for k, i in enumerate(order):
        running = max(running, min(1.0, (m - k) * pvalues[i]))
        out[i] = running
    return out


def verdict(x: str, y: str, poi: Estimate, holm_p: float, diff: float, alpha: float = 0.05) -> str:
    """Which arm is ahead, and by which criterion: the probability of improvement's
    interval excluding ½, and/or the Holm-adjusted Welch test rejecting at ``alpha``."""
    by_poi = x if poi.low > 0.5 else y if poi.high < 0.5 else None
    by_welch = (x if diff > 0 else y) if not math.isnan(holm_p) and holm_p < alpha else None
    if by_poi and by_welch and by_poi != by_welch:
        return "conflicting (PoI and Welch–Holm disagree)"
    if by_poi and by_welch:
        return f"{by_poi} ahead (PoI interval and Welch–Holm)"
    if by_poi:
        return f"{by_poi} ahead by the PoI interval only (Welch–Holm does not reject)"
    if by_welch:
        return f"{by_welch} ahead by Welch–Holm only (PoI interval contains 0.5)"
    return "not resolved"
