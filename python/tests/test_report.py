"""pednav_report (rliable statistics from results.csv) on synthetic data with known answers.

Pure Python: needs the ``report`` extra (rliable, scipy, matplotlib), not the simulator's
extension. Bootstrap replicates are kept small so the file runs in seconds.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rliable")
pytest.importorskip("scipy")

from pednav_report import data, stats
from pednav_report.__main__ import main

YAWS = (0.0, 90.0, 180.0, -90.0)
POINTS = tuple(range(14))


def write_results(path: Path, returns, runs: int = 2, oracle_column: dict[int, float] | None = None) -> Path:
    """A results.csv: ``returns(point, yaw, run)`` per episode; with a table.csv beside it
    whose oracle column is ``oracle_column`` (the scene's fingerprint), if given."""
    path.mkdir(parents=True, exist_ok=True)
    rows = ["point,yaw_deg,run,discounted_return,success,steps"]
    means = {}
    for p in POINTS:
        g_p = [returns(p, y, k) for y in YAWS for k in range(runs)]
        means[p] = sum(g_p) / len(g_p)
        for y in YAWS:
            for k in range(runs):
                g = returns(p, y, k)
                rows.append(f"{p},{y:g},{k},{g:.4f},{'true' if g > -50 else 'false'},10")
    (path / "results.csv").write_text("\n".join(rows) + "\n")
    if oracle_column is not None:
        t = ["point,episodes,mean,std,success_rate,oracle"]
        t += [f"{p},{len(YAWS) * runs},{means[p]:.4f},0.0,1.0,{oracle_column[p]:.4f}" for p in POINTS]
        (path / "table.csv").write_text("\n".join(t) + "\navg_int,,0.0,,,\navg_ext,,0.0,,,\n")
    return path / "results.csv"


RANDOM = -100.0  # the random walk's return everywhere
ORACLE = 0.0  # the oracle's: normalised score = (G + 100) / 100
SCENE = {p: ORACLE for p in POINTS}


def references(tmp: Path) -> tuple[data.Reference, data.Reference]:
    r = write_results(tmp / "random", lambda p, y, k: RANDOM, oracle_column=SCENE)
    o = write_results(tmp / "oracle", lambda p, y, k: ORACLE, runs=1, oracle_column=SCENE)
    return data.load_reference(str(r.parent), "random"), data.load_reference(str(o), "oracle")


def arm(tmp: Path, name: str, seeds: list, scene=SCENE) -> data.Arm:
    """An arm whose seed i scores ``seeds[i](point, yaw, run)`` (normalised)."""
    paths = [
        write_results(
            tmp / f"{name}-s{i}" / "eval" / "learned",
            lambda p, y, k, f=f: RANDOM + 100 * f(p, y, k),
            oracle_column=scene,
        )
        for i, f in enumerate(seeds)
    ]
    return data.parse_arm(f"{name}=" + ",".join(str(p.parent.parent.parent) for p in paths))


# ---------------------------------------------------------------- normalisation


def test_normalisation_per_pose_matches_hand_computed_values(tmp_path: Path) -> None:
    # Random walk: −200 at yaw 0, −100 elsewhere (mean of its two episodes: −210 and −190).
    rnd = write_results(tmp_path / "rnd", lambda p, y, k: (-210.0 if k == 0 else -190.0) if y == 0 else -100.0)
    # Oracle: +10 at point 3, yaw 0; −20 elsewhere.
    orc = write_results(tmp_path / "orc", lambda p, y, k: 10.0 if (p, y) == (3, 0.0) else -20.0, runs=1)
    run = write_results(tmp_path / "run", lambda p, y, k: -40.0 if k == 0 else -60.0)
    random, oracle = data.load_reference(str(rnd), "random"), data.load_reference(str(orc), "oracle")
    assert random.resolution == oracle.resolution == "pose"
    r = data.read_results(run)
    m = data.score_matrix([r], [(3, 0.0), (3, 90.0), (9, 0.0)], random, oracle)
    # (3, 0): episodes −40, −60 against −200 / +10: (160/210 + 140/210) / 2 = 150/210.
    # (3, 90): against −100 / −20: (60/80 + 40/80) / 2 = 0.625.  (9, 0): against −200 / −20: 150/180.
    np.testing.assert_allclose(m, [[150 / 210, 0.625, 150 / 180]])
    # The per-episode formula itself, and a reference at or above the oracle is refused.
    np.testing.assert_allclose(data.normalised([-50.0, 0.0, 10.0], -100.0, 0.0), [0.5, 1.0, 1.1])
    with pytest.raises(data.ReportError, match="not above"):
        data.normalised([0.0], 5.0, 5.0)


def test_table_csv_references_are_per_point_and_scene_mismatch_is_flagged(tmp_path: Path) -> None:
    # A random walk's table.csv (means −150 at every point) from another scene: point 11's oracle differs.
    other = dict(SCENE) | {11: 2.7186}
    write_results(tmp_path / "rnd", lambda p, y, k: -150.0, oracle_column=other)
    random = data.load_reference(str(tmp_path / "rnd" / "table.csv"), "random")
    assert random.resolution == "point" and random.value((4, 90.0)) == -150.0
    a = arm(tmp_path, "A", [lambda p, y, k: 0.5])
    oracle = data.load_reference("from-runs", "oracle", a.runs)
    assert oracle.value((11, 45.0)) == ORACLE
    warnings = data.scene_warnings(a.runs, [random, oracle])
    assert len(warnings) == 1 and "random" in warnings[0] and "point 11" in warnings[0]
    # Runs from two scenes cannot share a `from-runs` oracle.
    b = arm(tmp_path, "B", [lambda p, y, k: 0.5], scene=other)
    with pytest.raises(data.ReportError, match="differ"):
        data.load_reference("from-runs", "oracle", a.runs + b.runs)


def test_average_returns_are_the_tables_avg_int_and_ext(tmp_path: Path) -> None:
    r = data.read_results(write_results(tmp_path / "r", lambda p, y, k: -float(p) - k))
    # Per-point mean −p − 0.5; Avg.Int = mean over 0–7 = −4.0, Avg.Ext = mean over 8–13 = −11.0.
    assert r.average_return(data.AVERAGES["Int"]) == pytest.approx(-4.0)
    assert r.average_return(data.AVERAGES["Ext"]) == pytest.approx(-11.0)


# ---------------------------------------------------------------- rliable's aggregates


def test_iqm_and_optimality_gap_of_known_scores() -> None:
    # 2 runs × 4 tasks holding 1..8: the middle half is 3, 4, 5, 6 → IQM 4.5.
    m = np.arange(1.0, 9.0).reshape(2, 4)
    assert stats.iqm(m) == pytest.approx(4.5)
    # Scores 0.2, 0.6, 1.0, 1.4: clipped at 1 → mean 0.7 → gap 0.3.
    assert stats.optimality_gap(np.array([[0.2, 0.6], [1.0, 1.4]])) == pytest.approx(0.3)
    # Constant scores: every bootstrap replicate is the same, so the interval is a point.
    e = stats.aggregate_intervals({"c": np.full((3, 5), 0.8)}, reps=50, seed=0)["c"]
    assert (e["iqm"].value, e["iqm"].low, e["iqm"].high) == pytest.approx((0.8, 0.8, 0.8))
    assert (e["optimality_gap"].low, e["optimality_gap"].high) == pytest.approx((0.2, 0.2))


def test_intervals_are_reproducible_from_the_seed() -> None:
    m = np.random.default_rng(1).normal(0.5, 0.1, (3, 8))
    a = stats.aggregate_intervals({"m": m}, reps=200, seed=7)["m"]["iqm"]
    np.random.seed(123)  # whatever ran before does not matter
    b = stats.aggregate_intervals({"m": m}, reps=200, seed=7)["m"]["iqm"]
    assert a == b and a.low < a.value < a.high


def test_probability_of_improvement_dominating_and_identical_arms() -> None:
    rng = np.random.default_rng(0)
    y = rng.uniform(0.0, 0.5, (3, 6))
    x = y + 0.6  # every run of X beats every run of Y on every task
    e = stats.probability_of_improvement(x, y, reps=30, seed=0)
    assert (e.value, e.low, e.high) == (1.0, 1.0, 1.0)
    e = stats.probability_of_improvement(y, x, reps=30, seed=0)
    assert (e.value, e.low, e.high) == (0.0, 0.0, 0.0)
    e = stats.probability_of_improvement(y, y.copy(), reps=30, seed=0)
    assert e.value == 0.5 and e.low <= 0.5 <= e.high
    # One task, runs {1, 3} against {2}: P(X > Y) = 1/2 (one of two pairs).
    assert stats.probability_of_improvement(np.array([[1.0], [3.0]]), np.array([[2.0]]), reps=10, seed=0).value == 0.5


# ---------------------------------------------------------------- Welch and Holm


def test_welch_matches_the_formula() -> None:
    # x = 1, 2, 3 (var 1), y = 4, 6, 8 (var 4): t = −4 / √(5/3), df = (5/3)² / ((1/3)²/2 + (4/3)²/2) = 50/17.
    w = stats.welch([1, 2, 3], [4, 6, 8])
    assert w.diff == -4.0
    assert w.t == pytest.approx(-4 / math.sqrt(5 / 3))
    assert w.df == pytest.approx(50 / 17)
    import scipy.stats

    assert w.p == pytest.approx(2 * scipy.stats.t.sf(4 / math.sqrt(5 / 3), 50 / 17))
    half = scipy.stats.t.ppf(0.975, 50 / 17) * math.sqrt(5 / 3)
    assert (w.low, w.high) == pytest.approx((-4 - half, -4 + half))
    # Undefined: one seed, or no spread on either side.
    assert math.isnan(stats.welch([1.0], [2.0, 3.0]).p)
    assert math.isnan(stats.welch([1.0, 1.0], [2.0, 2.0]).p)


def test_holm_on_known_p_values() -> None:
    # Sorted 0.005, 0.01, 0.03, 0.04 → ×4, ×3, ×2, ×1 = 0.02, 0.03, 0.06, 0.04 → monotone: 0.02, 0.03, 0.06, 0.06.
    assert stats.holm([0.01, 0.04, 0.03, 0.005]) == pytest.approx([0.03, 0.06, 0.06, 0.02])
    assert stats.holm([0.5, 0.9]) == pytest.approx([1.0, 1.0])  # capped at 1
    out = stats.holm([0.01, math.nan, 0.02])  # NaN: not in the family (m = 2)
    assert out[0] == pytest.approx(0.02) and math.isnan(out[1]) and out[2] == pytest.approx(0.02)
    try:  # statsmodels comes with rliable (through arch): the same numbers
        from statsmodels.stats.multitest import multipletests
    except ImportError:
        return
    p = [0.2, 0.001, 0.04, 0.013, 0.9, 0.03]
    assert stats.holm(p) == pytest.approx(list(multipletests(p, method="holm")[1]))


def test_verdicts_name_the_criterion() -> None:
    ahead, level = stats.Estimate(0.9, 0.8, 1.0), stats.Estimate(0.5, 0.4, 0.6)
    assert stats.verdict("A", "B", ahead, 0.01, 0.2) == "A ahead (PoI interval and Welch–Holm)"
    assert stats.verdict("A", "B", ahead, 0.2, 0.2).startswith("A ahead by the PoI interval only")
    assert stats.verdict("A", "B", level, 0.01, -0.2).startswith("B ahead by Welch–Holm only")
    assert stats.verdict("A", "B", level, 0.2, 0.1) == "not resolved"


# ---------------------------------------------------------------- the command


def test_command_writes_the_report(tmp_path: Path) -> None:
    random, oracle = references(tmp_path)
    assert random.resolution == oracle.resolution == "pose"
    # Good: seed i scores 0.8 + 0.02 i everywhere; Poor: 0.3 + 0.02 i; Twin: Good's scores again.
    good = [lambda p, y, k, i=i: 0.8 + 0.02 * i for i in range(3)]
    poor = [lambda p, y, k, i=i: 0.3 + 0.02 * i for i in range(3)]
    for name, seeds in (("good", good), ("poor", poor), ("twin", good)):
        arm(tmp_path, name, seeds)
    out = tmp_path / "report"
    rc = main(
        [
            "--arm", f"Good={tmp_path}/good-s*",
            "--arm", f"Poor={tmp_path}/poor-s0,{tmp_path}/poor-s1,{tmp_path}/poor-s2",
            "--arm", f"Twin={tmp_path}/twin-s*",
            "--random", str(tmp_path / "random"),
            "--oracle", str(tmp_path / "oracle" / "results.csv"),
            "--out", str(out),
            "--reps", "100", "--poi-reps", "10", "--profile-reps", "20",
        ]
    )  # fmt: skip
    assert rc == 0
    r = json.loads((out / "report.json").read_text())
    assert (out / "performance_profile.png").stat().st_size > 10_000
    md = (out / "report.md").read_text()
    assert "IQM" in md and "performance_profile.png" in md and "Holm" in md
    assert r["tasks"]["Int"]["tasks"] == 8 * len(YAWS) and r["tasks"]["Ext"]["tasks"] == 6 * len(YAWS)
    g = r["arms"]["Good"]
    assert g["n"] == 3 and [x["run"] for x in g["runs"]] == ["good-s0", "good-s1", "good-s2"]
    for avg in ("Int", "Ext"):
        a = g["averages"][avg]
        # Scores 0.80, 0.82, 0.84: IQM of 3 × tasks cells = 0.82 (the middle half is all 0.82) and the mean too.
        assert a["iqm"]["value"] == pytest.approx(0.82)
        assert a["score_mean"] == pytest.approx(0.82) and a["score_std"] == pytest.approx(0.02)
        assert a["optimality_gap"]["value"] == pytest.approx(0.18)
        # Return = −100 + 100 · score: the table's Avg.Int / Avg.Ext.
        assert a["return_mean"] == pytest.approx(-18.0) and a["return_std"] == pytest.approx(2.0)
    pairs = {(p["x"], p["y"], p["average"]): p for p in r["pairs"]}
    assert len(pairs) == 6 and r["holm_family"] == 6
    gp = pairs[("Good", "Poor", "Int")]
    assert (gp["poi"]["value"], gp["poi"]["low"]) == (1.0, 1.0)
    assert gp["welch"]["diff"] == pytest.approx(0.5) and gp["holm_p"] < 0.05
    assert gp["verdict"] == "Good ahead (PoI interval and Welch–Holm)"
    gt = pairs[("Good", "Twin", "Ext")]
    assert gt["poi"]["value"] == 0.5 and gt["welch"]["diff"] == pytest.approx(0.0)
    assert gt["verdict"] == "not resolved"
    assert pairs[("Poor", "Twin", "Int")]["verdict"].startswith("Twin ahead")
    assert r["warnings"] == []


def test_command_reports_bad_input(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    references(tmp_path)
    rc = main(
        [
            "--arm",
            f"A={tmp_path}/nothing-*",
            "--random",
            str(tmp_path / "random"),
            "--oracle",
            "from-runs",
            "--out",
            str(tmp_path / "o"),
        ]
    )
    assert rc == 2 and "matches nothing" in capsys.readouterr().err


def test_parallel_probability_of_improvement_equals_serial(tmp_path: Path) -> None:
    from pednav_report.report import Settings, compute

    random, oracle = references(tmp_path)
    rng = np.random.default_rng(3)
    noise = {(p, y): rng.normal(0, 0.05, 3) for p in POINTS for y in YAWS}
    arms = [
        arm(tmp_path, "a", [lambda p, y, k, i=i: 0.6 + noise[p, y][i] for i in range(3)]),
        arm(tmp_path, "b", [lambda p, y, k, i=i: 0.62 + noise[p, y][(i + 1) % 3] for i in range(3)]),
    ]
    quiet = {"reps": 20, "poi_reps": 8, "profile_reps": 5, "log": lambda s: None}
    one = compute(arms, random, oracle, Settings(jobs=1, **quiet))
    two = compute(arms, random, oracle, Settings(jobs=2, **quiet))
    assert [p["poi"] for p in one["pairs"]] == [p["poi"] for p in two["pairs"]]
    assert 0.0 < one["pairs"][0]["poi"]["value"] < 0.5  # b is ahead by 0.02 on every task, but noisily
