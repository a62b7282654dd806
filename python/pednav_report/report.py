"""Compute the report's numbers and write ``report.md``, ``report.json`` and
``performance_profile.png``."""

from __future__ import annotations

import itertools
import json
import math
import sys
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass, field
from importlib import metadata
from pathlib import Path

import numpy as np

from . import stats
from .data import AVERAGES, Arm, Reference, ReportError, scene_warnings, score_matrix, task_poses


@dataclass
class Settings:
    reps: int = 50_000  # rliable's default for get_interval_estimates
    poi_reps: int = 2_000  # one replicate is one Mann–Whitney U per task: slow
    profile_reps: int = 2_000  # rliable's default for create_performance_profile
    seed: int = 0
    level: float = 0.95
    alpha: float = 0.05
    jobs: int = 1
    pairs: list[tuple[str, str]] | None = None  # None: every pair, in the arms' order
    averages: tuple[str, ...] = ("Int", "Ext")
    command: str = ""
    title: str = "Reliable-evaluation statistics (rliable)"
    log: Callable[[str], None] = field(default=lambda s: print(s, file=sys.stderr, flush=True))


def _versions() -> dict[str, str]:
    out = {}
    for pkg in ("rliable", "arch", "numpy", "scipy", "matplotlib"):
        try:
            out[pkg] = metadata.version(pkg)
        except metadata.PackageNotFoundError:
            out[pkg] = "?"
    return out


def _mean_std(v: list[float]) -> tuple[float, float]:
    a = np.asarray(v, dtype=float)
    return float(a.mean()), float(a.std(ddof=1)) if len(a) > 1 else 0.0


def _poi_job(args: tuple) -> stats.Estimate:
    x, y, reps, seed, level = args
    return stats.probability_of_improvement(x, y, reps=reps, seed=seed, level=level)


def compute(arms: list[Arm], random: Reference, oracle: Reference, s: Settings) -> dict:
    """Every number of the report, as plain data (what ``report.json`` holds)."""
    if len({a.name for a in arms}) != len(arms):
        raise ReportError("two arms have the same name")
    names = [a.name for a in arms]
    pairs = s.pairs or list(itertools.combinations(names, 2))
    for x, y in pairs:
        if x not in names or y not in names or x == y:
            raise ReportError(f"pair ({x}, {y}): not two of the arms {names}")
    all_runs = [r for a in arms for r in a.runs]
    out: dict = {
        "title": s.title,
        "command": s.command,
        "versions": _versions(),
        "settings": {
            "reps": s.reps,
            "poi_reps": s.poi_reps,
            "profile_reps": s.profile_reps,
            "seed": s.seed,
            "level": s.level,
            "alpha": s.alpha,
            "bootstrap": "rliable stratified bootstrap (runs resampled within each task), percentile intervals",
        },
        "references": {
            ref.role: {"source": ref.source, "resolution": ref.resolution, "description": ref.describe()}
            for ref in (random, oracle)
        },
        "warnings": scene_warnings(all_runs, [random, oracle]),
        "tasks": {},
        "arms": {a.name: {"runs": [], "averages": {}} for a in arms},
        "pairs": [],
    }
    matrices: dict[str, dict[str, np.ndarray]] = {}
    for avg in s.averages:
        points = AVERAGES[avg]
        poses = task_poses(arms, points)
        if not poses:
            raise ReportError(f"no episodes on points {points[0]}–{points[-1]} ({avg})")
        out["tasks"][avg] = {"points": list(points), "tasks": len(poses), "poses": [list(p) for p in poses]}
        matrices[avg] = {a.name: score_matrix(a.runs, poses, random, oracle) for a in arms}

    for a in arms:
        entry = out["arms"][a.name]
        for i, r in enumerate(a.runs):
            row = {"run": r.name, "path": str(r.path), "episodes": r.episodes, "success": r.success_rate()}
            for avg in s.averages:
                row[f"avg_{avg.lower()}_return"] = r.average_return(AVERAGES[avg])
                row[f"score_{avg.lower()}"] = float(matrices[avg][a.name][i].mean())
            entry["runs"].append(row)
        entry["n"] = len(a.runs)
        entry["success"] = float(np.mean(np.concatenate([np.concatenate(list(r.successes.values())) for r in a.runs])))

    for avg in s.averages:
        s.log(f"IQM and optimality gap on {avg} ({s.reps} replicates per arm)…")
        agg = stats.aggregate_intervals(matrices[avg], reps=s.reps, seed=s.seed, level=s.level)
        for a in arms:
            rows = out["arms"][a.name]["runs"]
            ret_m, ret_s = _mean_std([r[f"avg_{avg.lower()}_return"] for r in rows])
            sc_m, sc_s = _mean_std([r[f"score_{avg.lower()}"] for r in rows])
            out["arms"][a.name]["averages"][avg] = {
                "return_mean": ret_m,
                "return_std": ret_s,
                "score_mean": sc_m,
                "score_std": sc_s,
                "iqm": asdict(agg[a.name]["iqm"]),
                "optimality_gap": asdict(agg[a.name]["optimality_gap"]),
            }

    jobs = []
    for avg in s.averages:
        for x, y in pairs:
            jobs.append((matrices[avg][x], matrices[avg][y], s.poi_reps, s.seed, s.level))
    s.log(f"probability of improvement: {len(jobs)} comparisons × {s.poi_reps} replicates…")
    if s.jobs > 1:
        with ProcessPoolExecutor(s.jobs) as ex:
            pois = list(ex.map(_poi_job, jobs))
    else:
        pois = []
        for k, j in enumerate(jobs):
            pois.append(_poi_job(j))
            s.log(f"  {k + 1}/{len(jobs)}")
    k = 0
    for avg in s.averages:
        for x, y in pairs:
            sx = [r[f"score_{avg.lower()}"] for r in out["arms"][x]["runs"]]
            sy = [r[f"score_{avg.lower()}"] for r in out["arms"][y]["runs"]]
            out["pairs"].append(
                {
                    "x": x,
                    "y": y,
                    "average": avg,
                    "poi": asdict(pois[k]),
                    "welch": stats.welch(sx, sy, s.level).as_dict(),
                }
            )
            k += 1
    adjusted = stats.holm([p["welch"]["p"] for p in out["pairs"]])
    out["holm_family"] = sum(not math.isnan(p) for p in adjusted)
    for p, h in zip(out["pairs"], adjusted):
        p["holm_p"] = h
        p["verdict"] = stats.verdict(p["x"], p["y"], stats.Estimate(**p["poi"]), h, p["welch"]["diff"], s.alpha)

    s.log(f"performance profiles ({s.profile_reps} replicates)…")
    allv = np.concatenate([m.ravel() for d in matrices.values() for m in d.values()])
    lo = math.floor(allv.min() * 10) / 10
    hi = max(1.0, math.ceil(allv.max() * 10) / 10)
    taus = np.linspace(lo, hi, 201)
    out["profiles"] = {"taus": taus.tolist()}
    for avg in s.averages:
        prof, ci = stats.performance_profiles(matrices[avg], taus, reps=s.profile_reps, seed=s.seed, level=s.level)
        out["profiles"][avg] = {
            n: {
                "profile": np.asarray(prof[n]).tolist(),
                "low": np.asarray(ci[n][0]).tolist(),
                "high": np.asarray(ci[n][1]).tolist(),
            }
            for n in names
        }
    return out


def _f(v: float, d: int = 2, sign: bool = False) -> str:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "—"
    s = f"{v:+.{d}f}" if sign else f"{v:.{d}f}"
    return s.replace("-", "−")


def _ci(e: dict, d: int = 2) -> str:
    return f"{_f(e['value'], d)} [{_f(e['low'], d)}, {_f(e['high'], d)}]"


def _p(p: float) -> str:
    if math.isnan(p):
        return "—"
    return "< 0.001" if p < 0.001 else f"{p:.3f}"


def render_markdown(r: dict) -> str:
    st = r["settings"]
    lvl = f"{100 * st['level']:g} %"
    L = [f"# {r['title']}", ""]
    if r["command"]:
        L += ["Written by", "", "```bash", r["command"], "```", ""]
    v = r["versions"]
    L += [
        f"rliable {v['rliable']} (arch {v['arch']}), numpy {v['numpy']}, scipy {v['scipy']}, matplotlib {v['matplotlib']}.",
        "",
        "## What is computed",
        "",
        "Normalised score of an episode started at (point, yaw): (G − random) / (oracle − random) — 0 at the random "
        "walk's return, 1 at the oracle's.",
        "",
        f"- random walk: {r['references']['random']['description']}",
        f"- oracle: {r['references']['oracle']['description']}",
        "",
    ]
    tasks = "; ".join(
        f"{avg}: points {t['points'][0]}–{t['points'][-1]}, {t['tasks']} tasks" for avg, t in r["tasks"].items()
    )
    L += [
        f"A task is one start pose (point, yaw) — {tasks}. A run's (seed's) score on a task is the mean normalised score "
        "of its episodes from that pose; a *score matrix* is runs × tasks. IQM (interquartile mean over all runs × "
        "tasks), optimality gap (mean shortfall below 1, scores above 1 clipped), their intervals, the performance "
        "profiles and the probability of improvement are rliable's (`rliable.metrics`, `rliable.library`: stratified "
        f"bootstrap — each task's runs resampled — with {lvl} percentile intervals; {st['reps']:,} replicates for "
        f"IQM / optimality gap, {st['poi_reps']:,} for the probability of improvement, {st['profile_reps']:,} for the "
        f"profiles; NumPy's generator seeded with {st['seed']} before each call). The Welch test (scipy) compares "
        "the arms' per-seed mean scores; Holm's adjustment runs over every Welch test in this report "
        f"({r['holm_family']} tests). An arm is called ahead where the probability of improvement's interval excludes "
        f"0.5, or where the Holm-adjusted Welch p is below {st['alpha']:g}; the verdict says which.",
        "",
    ]
    if r["warnings"]:
        L += ["**Warnings**", ""] + [f"- {w}" for w in r["warnings"]] + [""]

    for avg in r["tasks"]:
        L += [
            f"## Avg.{avg} (points {r['tasks'][avg]['points'][0]}–{r['tasks'][avg]['points'][-1]})",
            "",
            f"| arm | n | Avg.{avg} return, mean ± sd | score, mean ± sd | IQM [{lvl} CI] | optimality gap [{lvl} CI] | per-seed score |",
            "|---|---|---|---|---|---|---|",
        ]
        for name, a in r["arms"].items():
            x = a["averages"][avg]
            per = ", ".join(_f(run[f"score_{avg.lower()}"], 3) for run in a["runs"])
            L.append(
                f"| {name} | {a['n']} | {_f(x['return_mean'], 1)} ± {_f(x['return_std'], 1)} | "
                f"{_f(x['score_mean'], 3)} ± {_f(x['score_std'], 3)} | {_ci(x['iqm'], 3)} | "
                f"{_ci(x['optimality_gap'], 3)} | {per} |"
            )
        L += [
            "",
            f"| X vs Y | P(X > Y) [{lvl} CI] | score X − Y [Welch {lvl} CI] | Welch t (df) | p | Holm p | verdict |",
            "|---|---|---|---|---|---|---|",
        ]
        for p in (p for p in r["pairs"] if p["average"] == avg):
            w = p["welch"]
            L.append(
                f"| {p['x']} vs {p['y']} | {_ci(p['poi'], 3)} | {_f(w['diff'], 3, True)} [{_f(w['low'], 3, True)}, "
                f"{_f(w['high'], 3, True)}] | {_f(w['t'], 2)} ({_f(w['df'], 1)}) | {_p(w['p'])} | {_p(p['holm_p'])} | "
                f"{p['verdict']} |"
            )
        L.append("")
    L += [
        "## Performance profile",
        "",
        "![performance profile](performance_profile.png)",
        "",
        "`performance_profile.png`: the fraction of run × task scores above τ for each arm (rliable's score "
        f"distribution), with its {lvl} stratified-bootstrap band, one panel per average.",
        "",
        "## Reading",
        "",
        "- Return columns: mean ± sample standard deviation over the n runs of each run's average over its "
        "validation points — the numbers `pednav-plot table` prints. Score columns: the same on the normalised scale.",
        "- How far the intervals can be trusted: rliable's stratified bootstrap resamples each task's runs "
        "independently of the other tasks' — right where every (run, task) is its own training run (an Atari game "
        "per agent). Here one run is one trained agent evaluated from every start, so a run's scores on the tasks "
        "are not independent (a seed that does well from one start does well from the others): with n seeds the "
        "IQM, optimality-gap and probability-of-improvement intervals show how consistent the arms are across "
        "start poses *for these seeds*, and are narrower than the spread between seeds warrants. The Welch test "
        "on seed means (n − 1 degrees of freedom per arm behind it) is the criterion that treats the seed as the "
        "unit; a verdict that rests on the PoI interval alone says so.",
        "",
    ]
    return "\n".join(L)


def draw_profiles(r: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from rliable import plot_utils

    avgs = list(r["tasks"])
    fig, axes = plt.subplots(1, len(avgs), figsize=(6.5 * len(avgs), 4.6), squeeze=False)
    taus = np.asarray(r["profiles"]["taus"])
    for ax, avg in zip(axes[0], avgs):
        prof = {n: np.asarray(v["profile"]) for n, v in r["profiles"][avg].items()}
        cis = {n: (np.asarray(v["low"]), np.asarray(v["high"])) for n, v in r["profiles"][avg].items()}
        plot_utils.plot_performance_profiles(
            prof,
            taus,
            performance_profile_cis=cis,
            ax=ax,
            xlabel=r"normalised score $\tau$ (0 random walk, 1 oracle)",
            ylabel=r"fraction of run $\times$ task scores $> \tau$",
            labelsize="medium",
            ticklabelsize="medium",
        )
        t = r["tasks"][avg]
        ax.set_title(f"Avg.{avg}: points {t['points'][0]}–{t['points'][-1]}, {t['tasks']} tasks", fontsize="medium")
        ax.legend(fontsize="small", loc="lower left")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def write(r: dict, out: Path) -> None:
    out.mkdir(parents=True, exist_ok=True)
    (out / "report.md").write_text(render_markdown(r))
    (out / "report.json").write_text(json.dumps(r, indent=1, ensure_ascii=False, allow_nan=True) + "\n")
    draw_profiles(r, out / "performance_profile.png")
