"""``python -m pednav_report.first_task``: hand-computed windows, the gate row, bad
input, and every first-task table in ``docs/results`` recomputed by the command its
README gives (printed into the README, or written to the file it redirects to)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from pednav_report.first_task import main
from readme_commands import readme_commands

ROOT = Path(__file__).resolve().parents[2]
RESULTS = ROOT / "docs" / "results"


def run_dir(tmp_path: Path, name: str, rows: list[str], passed: int | None = None) -> Path:
    run = tmp_path / name
    (run / "metrics").mkdir(parents=True)
    (run / "metrics" / "episodes.csv").write_text(
        "category,decision_steps,discounted_return,success\n" + "\n".join(rows) + "\n"
    )
    if passed is not None:
        (run / "stats").mkdir()
        (run / "stats" / "curriculum.json").write_text(json.dumps({"first_task_passed": {"decision_steps": passed}}))
    return run


def test_windows_best_mean_and_gate(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    # a, windows of 10 k up to 30 k: 0-10 k holds returns -10 and -20 (mean -15.0, one
    # success of 2 = 50 %); 10-20 k none ("—"); 20-30 k -4 (1, 100 %). Three first-task
    # episodes, so no 30-episode mean ("—"). No curriculum record: the gate reads "≤"
    # the first episode of another category, 25,000.
    a = run_dir(tmp_path, "a", ["first,3000,-10,1", "first,9000,-20,0", "ACL,25000,-1,1", "first,27000,-4,1"])
    # b: 35 first-task episodes, at 0, 800, …, 27,200 env steps: 30 of -1, then 5 of +5.
    # Window 0-10 k holds 13 (mean -1.0), 10-20 k 12 (-1.0), 20-30 k 10 (5 × -1, 5 × 5:
    # 2.0, 50 %). Best 30-episode mean: the last 30, (25 × -1 + 5 × 5) / 30 = 0.0. The
    # record says the gate opened at 1,234.
    b = run_dir(tmp_path, "b", [f"first,{800 * i},{-1 if i < 30 else 5},{int(i >= 30)}" for i in range(35)], passed=1234)
    assert main([f"A={a}", f"B={b}", "--window", "10000", "--until", "30000", "--gate"]) == 0
    assert capsys.readouterr().out.splitlines() == [
        "| env steps | A | B |",
        "|---|---|---|",
        "| 0–10 k | -15.0 (2, 50 %) | -1.0 (13, 0 %) |",
        "| 10–20 k | — | -1.0 (12, 0 %) |",
        "| 20–30 k | -4.0 (1, 100 %) | 2.0 (10, 50 %) |",
        "| best 30-episode mean | — | 0.0 |",
        "| gate opened by (env steps) | ≤ 25,000 | 1,234 |",
    ]


def test_budget_drops_later_episodes(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    a = run_dir(tmp_path, "a", ["first,1000,-10,1", "first,26000,-30,0"])
    assert main([f"A={a}", "--budget", "26000"]) == 0
    assert capsys.readouterr().out.splitlines()[2:4] == ["| 0–25 k | -10.0 (1, 100 %) |", "| 25–26 k | -30.0 (1, 0 %) |"]
    assert main([f"A={a}", "--budget", "25999"]) == 0
    assert capsys.readouterr().out.splitlines()[3] == "| 25–25 k | — |"


def test_the_last_row_ends_at_until_inclusive(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    # Windows of 25 k up to 30 k: an episode at 40,000 is past the last row (25-30 k);
    # one at exactly 30,000 is its end, counted.
    a = run_dir(tmp_path, "a", ["first,26000,-2,1", "first,30000,-4,1", "first,40000,-100,0"])
    assert main([f"A={a}", "--until", "30000"]) == 0
    assert capsys.readouterr().out.splitlines()[3] == "| 25–30 k | -3.0 (2, 100 %) |"


def test_bad_input_is_named(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main([f"A={tmp_path}"]) == 2
    assert "episodes.csv" in capsys.readouterr().err
    bad = run_dir(tmp_path, "bad", ["first,x,-1,1"])
    assert main([f"A={bad}"]) == 2
    assert "line 2" in capsys.readouterr().err
    assert main(["no-equals-sign"]) == 2
    assert main([f"A={bad}", "--window", "0"]) == 2
    assert "--window" in capsys.readouterr().err
    broken = run_dir(tmp_path, "broken", ["first,1,-1,1"])
    (broken / "stats").mkdir()
    (broken / "stats" / "curriculum.json").write_text("{not json")
    assert main([f"A={broken}", "--gate"]) == 2
    assert "curriculum.json" in capsys.readouterr().err


COMMANDS = [
    (readme, c) for readme in sorted(RESULTS.glob("*/README.md")) for c in readme_commands(readme, "pednav_report.first_task")
]


def test_the_folders_use_the_command() -> None:
    assert {r.parent.name for r, _ in COMMANDS} >= {"pixel-recipe", "scene-learning", "pixel-recipe-pilots", "pixel-ablations"}


@pytest.mark.parametrize(("readme", "command"), COMMANDS, ids=lambda x: x.parent.name if isinstance(x, Path) else "")
def test_every_first_task_table_recomputes(
    readme: Path, command, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.chdir(ROOT)
    assert main(command.argv) == 0
    out = capsys.readouterr().out
    if command.output is not None:
        assert (ROOT / command.output).read_text() == out
    else:
        assert out.strip() in readme.read_text(), f"{readme}: the command's table is not in the README:\n{out}"
