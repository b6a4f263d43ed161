"""sph validate: one line per metric with its tolerance and verdict, a plot per case, the exit code
follows the verdicts, and bad case names are refused."""
import pytest

from launch.cli import main
from launch.validate import MARTIN_MOYCE_T, MARTIN_MOYCE_Z, Metric, run_validate


def test_metric_verdicts():
    assert Metric("a", 0.01, 0.05).passed and not Metric("b", 0.06, 0.05).passed
    assert not Metric("c", float("nan"), 0.05).passed
    assert Metric("d", 0.06, 0.05).line().split()[-1] == "FAIL"


def test_martin_moyce_data_is_the_digitized_table():
    assert len(MARTIN_MOYCE_T) == len(MARTIN_MOYCE_Z) == 15
    assert MARTIN_MOYCE_T[0] == 0.832 and MARTIN_MOYCE_Z[-1] == 13.970


def test_a_case_prints_its_metrics_writes_its_plot_and_sets_the_exit_code(tmp_path, capsys):
    rc = run_validate(["dam_break"], quick=True, out=tmp_path)
    lines = [line for line in capsys.readouterr().out.splitlines() if line.startswith("dam_break.")]
    assert len(lines) == 1
    verdict = lines[0].split()[3]
    assert verdict in ("PASS", "FAIL") and rc == (0 if verdict == "PASS" else 1)
    assert (tmp_path / "dam_break.png").stat().st_size > 10_000


def test_unknown_cases_are_refused(capsys):
    assert main(["validate", "sloshing"]) == 2
    assert "choose from hydrostatic, dam_break, taylor_green" in capsys.readouterr().err
