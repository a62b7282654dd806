"""``python -m pednav_report.safety``: hand-computed values, bad input, and every traffic
table in ``docs/results`` recomputed by the command its README gives.

The unit tests write small ``results.csv`` files whose summaries are worked out by hand
in the comments. The docs tests read each results README's fenced ``bash`` blocks, run
every ``python -m pednav_report.safety`` command there (from the repository root, as
the README says) and require each table line it prints to appear in that README
verbatim; every ``safety.md`` must equal the per-point table of the ``results.csv``
beside it.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from pednav_report.data import ReportError
from pednav_report.safety import References, main, per_point_table, summarise
from readme_commands import readme_commands

ROOT = Path(__file__).resolve().parents[2]
RESULTS = ROOT / "docs" / "results"
HEADER = "point,yaw_deg,run,discounted_return,success,steps,vehicle_hits,dont_walk_entries,pedestrian_bumps,vehicle_bumps,kerb_wait_steps"


def write(path: Path, rows: list[str], header: str = HEADER) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(header + "\n" + "\n".join(rows) + "\n")
    return path


def test_summary_matches_hand_computed_values(tmp_path: Path) -> None:
    # Point 0: returns -10 and -20 (mean -15); point 1: -30 (Int = mean(-15, -30) = -22.5).
    # Point 8: -40; point 9: -60 (Ext = -50). Successes 2 of 5 = 40 %.
    # Hits 1 in 5 episodes = 20 per 100; don't-walk 3 / 5 = 60; bumps 5 / 5 = 100;
    # kerb wait (4 + 0 + 0 + 8 + 0) / 5 = 2.4 steps = 0.6 s at 0.25 s a step.
    f = write(
        tmp_path / "r" / "results.csv",
        [
            "0,0,0,-10,true,5,0,1,2,0,4",
            "0,45,0,-20,false,9,1,0,0,0,0",
            "1,0,0,-30,false,9,0,2,0,0,0",
            "8,0,0,-40,true,9,0,0,3,1,8",
            "9,0,0,-60,false,9,0,0,0,0,0",
        ],
    )
    s = summarise(f)
    assert (s.avg_int, s.avg_ext, s.success, s.episodes) == (-22.5, -50.0, 40.0, 5)
    assert (s.hits, s.dont_walk, s.bumps) == (20.0, 60.0, 100.0)
    assert s.kerb_wait_s == pytest.approx(0.6)
    assert s.name == "r"


def test_gap_and_arm_spread(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    # References: random Int/Ext = -100 / -200, oracle 0 / 0. Runs a (-50 / -100) and
    # b (-30 / -60): arm mean -40 / -80, gap (−40 + 100) / 100 = 0.60 and 0.60;
    # sample sd of (-50, -30) = 14.142… → 14.1; of (-100, -60) = 28.3.
    refs = tmp_path / "refs"
    for name, (i, e) in {"random": (-100, -200), "oracle": (0, 0)}.items():
        write(refs / name / "results.csv", [f"0,0,0,{i},false,1,0,0,0,0,0", f"8,0,0,{e},false,1,0,0,0,0,0"])
    for name, (i, e) in {"a": (-50, -100), "b": (-30, -60)}.items():
        write(tmp_path / name / "eval" / "learned" / "results.csv", [f"0,0,0,{i},true,1,0,0,0,0,0", f"8,0,0,{e},true,1,0,0,0,0,0"])
    assert References.load(refs).gap(-40, -80) == "0.60 / 0.60"
    rc = main(["--refs", str(refs), "--arms-only", "--arm", f"x, y={tmp_path / 'a'},{tmp_path / 'b'}"])
    out = capsys.readouterr().out
    assert rc == 0
    assert "| x, y | 2 | -40.0 ± 14.1 | -80.0 ± 28.3 | 0.60 / 0.60 | 100.0 ± 0.0 % | 0.0 ± 0.0 |" in out


def test_results_without_traffic_columns_read_as_dashes(tmp_path: Path) -> None:
    f = write(tmp_path / "results.csv", ["0,0,0,-1,true,3"], header="point,yaw_deg,run,discounted_return,success,steps")
    s = summarise(f)
    assert s.hits is None and s.kerb_wait_s is None and s.success == 100.0


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ("point,yaw_deg\n0,0\n", "missing columns"),
        (HEADER + "\n", "no episodes"),
        (HEADER + "\nzero,0,0,-1,true,3,0,0,0,0,0\n", "line 2"),
    ],
)
def test_bad_files_are_named(tmp_path: Path, content: str, message: str) -> None:
    f = tmp_path / "results.csv"
    f.write_text(content)
    with pytest.raises(ReportError, match=message) as e:
        summarise(f)
    assert str(f) in str(e.value)


def test_bad_arguments_exit_2_naming_them(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["--arm", f"a={tmp_path}"]) == 2
    assert "--refs" in capsys.readouterr().err
    assert main(["--refs", str(tmp_path), "--arm", f"a={tmp_path}"]) == 2
    assert "random: no results.csv" in capsys.readouterr().err
    assert main([]) == 2
    assert "--arm" in capsys.readouterr().err
    assert main(["--per-point", str(tmp_path), "--dt", "0"]) == 2
    assert "--dt" in capsys.readouterr().err


def safety_commands(readme: Path) -> list[list[str]]:
    """The ``python -m pednav_report.safety`` commands a README prints tables with."""
    return [c.argv for c in readme_commands(readme, "pednav_report.safety") if c.output is None]


READMES = sorted(p for p in RESULTS.glob("*/README.md") if safety_commands(p))


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
    for argv in safety_commands(readme):
        assert main(argv) == 0, argv
        for line in capsys.readouterr().out.splitlines():
            if line.strip():
                assert line in text, f"{readme}: the command {argv} prints a line the README lacks:\n{line}"


SAFETY_MD = sorted(RESULTS.rglob("safety.md"))


def test_there_are_per_point_tables() -> None:
    assert len(SAFETY_MD) >= 3


@pytest.mark.parametrize("table", SAFETY_MD, ids=lambda p: str(p.parent.relative_to(RESULTS)))
def test_every_per_point_table_recomputes(table: Path) -> None:
    assert table.read_text().strip() == per_point_table(table.parent / "results.csv")
