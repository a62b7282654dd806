"""``python -m pednav_report.traffic``: hand-computed values, bad input, and every traffic
table in ``docs/results`` recomputed by the command its README gives.

The unit tests write small ``results.csv`` files whose figures are worked out by hand in
the comments. The docs tests run every ``python -m pednav_report.traffic`` command of
the results READMEs (``readme_commands``) from the repository root and require the
tables it prints, whole, in that README; every ``safety.md`` must equal the per-point
table of the ``results.csv`` beside it.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from pednav_report.common import ReportError
from pednav_report.traffic import References, main, per_point_table, summarise
from readme_commands import readme_commands

ROOT = Path(__file__).resolve().parents[2]
RESULTS = ROOT / "docs" / "results"
COLUMNS = (
    "point,yaw_deg,run,discounted_return,success,steps,"
    "vehicle_hits,dont_walk_entries,pedestrian_bumps,vehicle_bumps,kerb_wait_steps"
)


def write(path: Path, rows: list[str], header: str = COLUMNS) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(header + "\n" + "\n".join(rows) + "\n")
    return path


def evaluation(path: Path, interior: float, exterior: float, success: str = "true", extra: str = "0,0,0,0,0") -> Path:
    """One episode per validation point: `interior` from points 0-7, `exterior` from 8-13."""
    rows = [f"{p},0,0,{interior if p < 8 else exterior},{success},1,{extra}" for p in range(14)]
    return write(path, rows)


def test_summary_matches_hand_computed_values(tmp_path: Path) -> None:
    # Point 0: returns -10 and -20 (mean -15); points 1-7: -30 (Avg.Int = (-15 + 7 × -30) / 8
    # = -28.125). Points 8-13: -40 and, at point 9, -60 (Avg.Ext = (5 × -40 - 60) / 6).
    # 15 episodes; successes: the two at point 0 = 2 / 15. Per 100 episodes: hits 1 → 100 / 15;
    # don't-walk 1 + 2 = 3 → 20; bumps 2 + 3 = 5 → 100 / 3. Kerb wait 4 + 8 = 12 steps over
    # 15 episodes = 0.8 steps = 0.2 s at 0.25 s a step.
    rows = ["0,0,0,-10,true,5,0,1,2,0,4", "0,45,0,-20,true,9,1,0,0,0,0"]
    rows += [f"{p},0,0,-30,false,9,0,{2 if p == 1 else 0},0,0,0" for p in range(1, 8)]
    rows += [f"{p},0,0,{-60 if p == 9 else -40},false,9,0,0,{3 if p == 8 else 0},1,{8 if p == 8 else 0}" for p in range(8, 14)]
    s = summarise(write(tmp_path / "r" / "results.csv", rows))
    assert s.avg_int == -28.125
    assert (s.avg_ext, s.success) == pytest.approx((-260 / 6, 200 / 15))
    assert (s.hits, s.dont_walk, s.bumps) == pytest.approx((100 / 15, 20.0, 100 / 3))
    assert s.kerb_wait_s == pytest.approx(0.2)
    assert s.name == "r"


def refs_folder(tmp_path: Path) -> Path:
    """References: random Avg.Int / Avg.Ext -100 / -200, oracle 0 / 0."""
    refs = tmp_path / "refs"
    evaluation(refs / "random" / "results.csv", -100, -200, "false")
    evaluation(refs / "oracle" / "results.csv", 0, 0)
    return refs


def test_gap_and_arm_spread(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    # Runs a (-50 / -100) and b (-30 / -60): arm mean -40 / -80, gap (-40 + 100) / 100 =
    # 0.60 and (-80 + 200) / 200 = 0.60; sample sd of (-50, -30) = 14.142… → 14.1, of
    # (-100, -60) 28.3; b's one hit per 14 episodes = 7.14 per 100, a's none: 3.6 ± 5.1.
    refs = refs_folder(tmp_path)
    evaluation(tmp_path / "a" / "eval" / "learned" / "results.csv", -50, -100)
    b = evaluation(tmp_path / "b" / "eval" / "learned" / "results.csv", -30, -60)
    b.write_text(b.read_text().replace("\n0,0,0,-30,true,1,0,", "\n0,0,0,-30,true,1,1,", 1))
    assert References.load(refs).gap(-40, -80) == "0.60 / 0.60"
    assert main(["--refs", str(refs), "--column", "arm", "--arm", f"x, y={tmp_path / 'a'},{tmp_path / 'b'}"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[2] == "| x, y | a | -50.0 | -100.0 | 0.50 / 0.50 | 100.0 % | 0.0 | 0.0 | 0.0 | 0.0 s |"
    assert out[3] == "| x, y | b | -30.0 | -60.0 | 0.70 / 0.70 | 100.0 % | 7.1 | 0.0 | 0.0 | 0.0 s |"
    assert out[7] == (
        "| x, y | 2 | -40.0 ± 14.1 | -80.0 ± 28.3 | 0.60 / 0.60 | 100.0 ± 0.0 % | 3.6 ± 5.1 | 0.0 ± 0.0 | "
        "0.0 ± 0.0 | 0.0 ± 0.0 s |"
    )


def test_results_without_traffic_columns_read_as_dashes(tmp_path: Path) -> None:
    rows = [f"{p},0,0,-1,true,3" for p in range(14)]
    s = summarise(write(tmp_path / "results.csv", rows, header="point,yaw_deg,run,discounted_return,success,steps"))
    assert s.hits is None and s.kerb_wait_s is None and s.success == 100.0


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ("point,yaw_deg\n0,0\n", "missing columns"),
        (COLUMNS + "\n", "no episodes"),
        (COLUMNS + "\nzero,0,0,-1,true,3,0,0,0,0,0\n", "line 2"),
        (COLUMNS + "\n0,0,0,-1,true,3,0,0,0,0,0\n", r"no episodes from validation points \[1, 2"),
    ],
)
def test_bad_files_are_named(tmp_path: Path, content: str, message: str) -> None:
    f = tmp_path / "results.csv"
    f.write_text(content)
    with pytest.raises(ReportError, match=message) as e:
        summarise(f)
    assert str(f) in str(e.value)


def test_bad_arguments_exit_2_naming_them(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    refs = refs_folder(tmp_path)
    cases = [
        (["--arm", f"a={tmp_path}"], "--refs"),
        (["--refs", str(tmp_path), "--arm", f"a={refs}/oracle"], "random: no results.csv"),
        ([], "--arm"),
        (["--per-point", str(tmp_path), "--dt", "0"], "--dt"),
        (["--refs", str(refs), "--arm", "a=,"], "no runs"),
        (["--refs", str(refs), "--arm", f"a={refs}/oracle", "--refs-for", f"b={refs}"], "names no --arm"),
    ]
    for argv, message in cases:
        assert main(argv) == 2, argv
        assert message in capsys.readouterr().err, argv


def test_references_without_a_gap_and_mixed_arms_are_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    same = tmp_path / "same"
    evaluation(same / "random" / "results.csv", -5, -5)
    evaluation(same / "oracle" / "results.csv", -5, -5)
    assert main(["--refs", str(same), "--arm", f"a={same}/oracle"]) == 2
    assert "no gap to close" in capsys.readouterr().err
    refs = refs_folder(tmp_path)
    plain = write(tmp_path / "plain" / "results.csv", [f"{p},0,0,-1,true,3" for p in range(14)], "point,yaw_deg,run,discounted_return,success,steps")
    assert main(["--refs", str(refs), "--arm", f"a={refs}/oracle,{plain}"]) == 2
    assert "mixes evaluations with and without traffic" in capsys.readouterr().err


def table_commands(readme: Path) -> list[list[str]]:
    """The ``python -m pednav_report.traffic`` commands a README prints tables with."""
    return [c.argv for c in readme_commands(readme, "pednav_report.traffic") if c.output is None]


READMES = sorted(p for p in RESULTS.glob("*/README.md") if table_commands(p))


def test_the_traffic_folders_use_the_command() -> None:
    assert {p.parent.name for p in READMES} >= {
        "traffic-learning",
        "traffic-horizon",
        "traffic-signal-phase",
        "traffic-1m",
        "traffic-warm-start",
    }


@pytest.mark.parametrize("readme", READMES, ids=lambda p: p.parent.name)
def test_every_traffic_table_recomputes_from_its_results_csv(
    readme: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.chdir(ROOT)
    text = readme.read_text()
    for argv in table_commands(readme):
        assert main(argv) == 0, argv
        for table in capsys.readouterr().out.strip().split("\n\n"):
            assert table in text, f"{readme}: the command {argv} prints a table the README lacks:\n{table}"


SAFETY_MD = sorted(RESULTS.rglob("safety.md"))


def test_there_are_per_point_tables() -> None:
    assert len(SAFETY_MD) >= 3


@pytest.mark.parametrize("table", SAFETY_MD, ids=lambda p: str(p.parent.relative_to(RESULTS)))
def test_every_per_point_table_recomputes(table: Path) -> None:
    assert table.read_text().strip() == per_point_table(table.parent / "results.csv")
