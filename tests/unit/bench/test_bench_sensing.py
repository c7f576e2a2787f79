"""bench/bench_sensing.py: its arguments are checked, and one round measures every part.

No timing is asserted: the figures are the bench's to print (docs/BENCHMARKS.md).
"""

from __future__ import annotations

from pathlib import Path

import pytest

from bench import bench_sensing


def test_defaults() -> None:
    args = bench_sensing.parse_args([])
    assert args.sizes == [1000, 10000]
    assert (args.rounds, args.passes, args.tree) == (3, 32, None)


@pytest.mark.parametrize(
    "argv",
    [
        ["--sizes", "0"],
        ["--sizes", "-3"],
        ["--sizes", "ten"],
        ["--sizes", "20001"],
        ["--sizes"],
        ["--rounds", "0"],
        ["--rounds", "51"],
        ["--passes", "0"],
        ["--passes", "2.5"],
        ["--tree", "/nonexistent/checkout"],
        ["--no-such-flag"],
    ],
)
def test_bad_arguments_are_refused(argv: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_:
        bench_sensing.parse_args(argv)
    assert exit_.value.code == 2
    assert "error:" in capsys.readouterr().err


def test_the_same_tree_twice_is_refused(capsys: pytest.CaptureFixture[str]) -> None:
    here = str(Path(bench_sensing.__file__).resolve().parent.parent)
    with pytest.raises(SystemExit):
        bench_sensing.parse_args(["--tree", here, "--tree", here])
    assert "twice" in capsys.readouterr().err


def test_one_round_measures_every_part() -> None:
    subject = bench_sensing._Subject(300)
    res = subject.measure(2, threads=True)
    for part in ("noise", "circles", "ir", "ambient", "kernel", "pass"):
        assert part in res
    assert res["pass"] > 0.0 and res["kernel"] > 0.0
