"""What every ``pednav_report`` command shares, in the standard library alone: the
Table III averages, where a run keeps its results, the error type, and how an arm's
``NAME=PATHS`` is read. The descriptive tables (:mod:`pednav_report.traffic`,
:mod:`pednav_report.first_task`) import only this, so they run without NumPy or
rliable."""

from __future__ import annotations

import glob
from pathlib import Path

#: The Table III averages: name → validation points (``protocol::INTERIOR`` is 0..8).
AVERAGES: dict[str, tuple[int, ...]] = {"Int": tuple(range(8)), "Ext": tuple(range(8, 14))}

#: Where a run directory keeps its validation-protocol results.
DEFAULT_RESULTS = "eval/learned/results.csv"


class ReportError(ValueError):
    """An input the report cannot use; the message names the file or the flag."""


def split_named(text: str, flag: str, what: str = "PATH[,PATH…]") -> tuple[str, str]:
    """``NAME=VALUE`` → (name, value), split at the first ``=`` (a name may hold commas,
    never ``=``); both must be non-empty."""
    name, sep, value = text.partition("=")
    if not sep or not name.strip() or not value.strip():
        raise ReportError(f"{flag} `{text}`: expected NAME={what}")
    return name.strip(), value.strip()


def expand(spec: str, results: str = DEFAULT_RESULTS) -> list[Path]:
    """The results.csv files of an arm: comma-separated paths or globs, each a
    ``results.csv``, a directory holding one, or a run directory (``<dir>/<results>``)."""
    out: list[Path] = []
    for part in (s.strip() for s in spec.split(",")):
        if not part:
            continue
        matches = sorted(glob.glob(part)) if glob.has_magic(part) else [part]
        if not matches:
            raise ReportError(f"{part}: matches nothing")
        for m in matches:
            p = Path(m)
            if p.is_file():
                out.append(p)
            elif (p / "results.csv").is_file():
                out.append(p / "results.csv")
            elif (p / results).is_file():
                out.append(p / results)
            else:
                raise ReportError(f"{m}: no results.csv (nor {results}) here")
    if not out:
        raise ReportError(f"`{spec}`: no runs")
    return out


def run_name(path: Path) -> str:
    """A run's label: the run directory's name (``…/<run>/eval/learned/results.csv``),
    else the folder holding the file."""
    parts = Path(path).parts
    if len(parts) >= 4 and parts[-3] == "eval":
        return parts[-4]
    return Path(path).parent.name or str(path)
