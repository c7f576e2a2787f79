"""bench/engine_ab.py: its arguments are checked, and a short A/A run reports both trees.

No timing is asserted: the figures are the bench's to print (docs/BENCHMARKS.md).
"""

from __future__ import annotations

from pathlib import Path

import pytest

from bench import engine_ab

ROOT = str(Path(engine_ab.__file__).resolve().parent.parent)


@pytest.mark.parametrize(
    "argv",
    [
        [],
        ["--trees", ROOT],
        ["--trees", ROOT, "/nonexistent/checkout"],
        ["--trees", ROOT, ROOT, "--robots", "0"],
        ["--trees", ROOT, ROOT, "--rounds", "-1"],
        ["--trees", ROOT, ROOT, "--ticks", "ten"],
    ],
)
def test_bad_arguments_are_refused(argv: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_:
        engine_ab.main(argv)
    assert exit_.value.code == 2
    assert "error:" in capsys.readouterr().err


def test_an_a_a_run_reports_both_trees_and_their_ratio(capsys: pytest.CaptureFixture[str]) -> None:
    engine_ab.main(["--trees", ROOT, ROOT, "--robots", "40", "--rounds", "2", "--ticks", "5"])
    out = capsys.readouterr().out
    rounds = [line for line in out.splitlines() if line.strip().startswith("round ")]
    assert len(rounds) == 2 and all(line.endswith(" ms") for line in rounds), out
    results = [line for line in out.splitlines() if "simulated s per wall s" in line]
    assert len(results) == 2 and all(line.startswith(ROOT) for line in results), out
    assert "first tree over second, per round: median" in out
