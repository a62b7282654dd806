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
:mod:`pednav_report.safety` (the traffic folders' returns, success and safety counts
per run and arm) and :mod:`pednav_report.first_task` (the first-task episodes per
window of env steps, and when the gate opened).

Pure Python: it does not import the simulator's extension (``pednav_gym``). The
module docs of :mod:`pednav_report.data` define the normalised score and the tasks.
"""

from .data import AVERAGES, Arm, Reference, ReportError, load_reference, parse_arm, read_results, score_matrix
from .stats import holm, iqm, optimality_gap, probability_of_improvement, welch

__all__ = [
    "AVERAGES",
    "Arm",
    "Reference",
    "ReportError",
    "holm",
    "iqm",
    "load_reference",
    "optimality_gap",
    "parse_arm",
    "probability_of_improvement",
    "read_results",
    "score_matrix",
    "welch",
]
