"""bench/bench_enki.py: its arguments are checked, and Enki's side runs the bench's world.

No timing is asserted: the figures are the bench's to print (docs/BENCHMARKS.md).
The Enki program's test needs g++ and Debian's libenki-dev; without them it is
skipped and says how to install them.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from bench import bench_enki


def test_defaults_are_the_issue_sizes() -> None:
    args = bench_enki.parse_args([])
    assert args.sizes == [10, 35, 100, 1000, 3000]
    assert args.repeats == 3
    assert args.drives == ["joints", "discs"]  # the old lab default and today's
    assert not args.full
    assert bench_enki.parse_args(["--full"]).full


@pytest.mark.parametrize(
    "argv",
    [
        ["--sizes", "0"],
        ["--sizes", "-3"],
        ["--sizes", "ten"],
        ["--sizes", "10", "20001"],
        ["--sizes"],
        ["--sim-seconds", "0"],
        ["--sim-seconds", "-1"],
        ["--sim-seconds", "nan"],
        ["--sim-seconds", "inf"],
        ["--swarm-seconds", "601"],
        ["--repeats", "0"],
        ["--repeats", "2.5"],
        ["--repeats", "51"],
        ["--drives", "wheels"],
        ["--drives", "joints", "joints"],
        ["--no-such-flag"],
    ],
)
def test_bad_arguments_are_refused(argv: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_:
        bench_enki.parse_args(argv)
    assert exit_.value.code == 2
    assert "error:" in capsys.readouterr().err


def test_without_libenki_the_bench_says_how_to_install_it(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    monkeypatch.setattr(bench_enki, "ENKI_HEADER", tmp_path / "Khepera.h")
    assert bench_enki.main(["--sizes", "10", "--repeats", "1"]) == 2
    err = capsys.readouterr().err
    assert "is not installed" in err  # libenki-dev, or g++ where that is missing too
    assert "apt-get install -y g++ libenki-dev" in err


def test_a_result_line_is_parsed_and_a_bad_one_refused() -> None:
    run = bench_enki.parse_enki_line(
        "enki n=10 steps=100 sim_s=1 cpu_s=0.002 sim_per_cpu=500 ir_updates_per_sim_s=100 inside=10"
    )
    assert (run.n, run.steps, run.sim_s, run.inside) == (10, 100, 1.0, 10)
    for bad in ("", "ours n=10", "enki n=10 steps", "enki n=10 steps=100"):
        with pytest.raises(ValueError):
            bench_enki.parse_enki_line(bad)


def test_the_scenario_file_holds_the_bench_world(tmp_path: Path) -> None:
    world = bench_enki.scenario_world(100)
    assert not world.lights  # Enki has no lights
    assert world.sensor_period_s == pytest.approx(0.01)  # IR every 10 ms, as Enki
    path = tmp_path / "n100.txt"
    bench_enki.write_scenario(world, path)
    kinds = [line.split()[0] for line in path.read_text().splitlines()]
    assert kinds.count("arena") == 1
    assert kinds.count("pillar") == len(world.obstacles) == 2  # one per 50 robots
    assert kinds.count("robot") == 100


@pytest.fixture(scope="module")
def enki_program(tmp_path_factory: pytest.TempPathFactory) -> Path:
    reason = bench_enki.enki_missing()
    if reason:
        pytest.skip(f"Enki's program cannot be built: {reason}")
    return bench_enki.compile_enki(tmp_path_factory.mktemp("bench-enki"))


def test_enki_runs_one_second_of_ten_robots(enki_program: Path, tmp_path: Path) -> None:
    scenario = tmp_path / "n10.txt"
    bench_enki.write_scenario(bench_enki.scenario_world(10), scenario)
    run = bench_enki.run_enki(enki_program, scenario, 1.0)
    assert run.n == 10
    assert run.steps == 100 and run.sim_s == pytest.approx(1.0)
    assert run.ir_updates_per_sim_s == pytest.approx(100.0)  # sensors every 10 ms
    assert run.inside == 10  # the walls held every robot
    assert run.cpu_s >= 0 and run.sim_per_cpu > 0


def test_enki_refuses_a_bad_scenario(enki_program: Path, tmp_path: Path) -> None:
    scenario = tmp_path / "bad.txt"
    scenario.write_text("arena 600\nrobot 1 2\n")
    with pytest.raises(RuntimeError, match="bad line"):
        bench_enki.run_enki(enki_program, scenario, 1.0)
