"""pednav_report — the field's reliable-evaluation statistics for pednav's evaluations.

From the per-episode ``results.csv`` files of ``pednav-eval`` (one per run, i.e. per
seed), grouped into arms, it computes with the ``rliable`` package (Agarwal et al.,
"Deep RL at the edge of the statistical precipice", NeurIPS 2021) the interquartile
mean and optimality gap of normalised scores with stratified-bootstrap intervals,
performance profiles and the probability of improvement between arms, and with scipy
a Welch t-test on seed means, Holm-adjusted over the pairs reported::

    python -m pednav_report --arm "A=runs/a-s*" --arm "B=runs/b-s1,runs/b-s2" \\
        --random docs/results/…/eval-random --oracle from-runs --out report/

Two descriptive tables sit beside it, each a module with its own command:
:mod:`pednav_report.traffic` (the traffic folders' returns, success and safety counts
per run and arm) and :mod:`pednav_report.first_task` (the first-task episodes per
window of env steps, and when the gate opened).

Those two need only the standard library. Pure Python: nothing here imports the
simulator's extension (``pednav_gym``). The module docs of :mod:`pednav_report.data`
define the normalised score and the tasks.
"""

from importlib import import_module

from .common import AVERAGES, ReportError

#: Names served from the modules that need NumPy, SciPy and rliable, imported on first
#: use so that ``pednav_report.traffic`` and ``pednav_report.first_task`` run with the
#: standard library alone.
_LAZY = {
    "Arm": "data",
    "Reference": "data",
    "load_reference": "data",
    "parse_arm": "data",
    "read_results": "data",
    "score_matrix": "data",
    "holm": "stats",
    "iqm": "stats",
    "optimality_gap": "stats",
    "probability_of_improvement": "stats",
    "welch": "stats",
}


def __getattr__(name: str):
    if name in _LAZY:
        return getattr(import_module(f".{_LAZY[name]}", __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["AVERAGES", "ReportError", *_LAZY]
