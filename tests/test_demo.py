"""``simshear demo``'s figure shows the error: beside each run's 3-D paths, its path from above coloured by the
contact error and the error over time."""

from pathlib import Path

import numpy as np
import pytest


def synthetic_runs(steps: int = 40) -> dict:
    t = np.linspace(0.0, 2.0 * np.pi, steps)
    target = np.stack([30.0 * np.cos(t), 30.0 * np.sin(t), np.zeros(steps)], axis=1)
    errors = 0.2 + 0.1 * np.sin(3.0 * t) ** 2
    sensor = target + np.stack([errors, np.zeros(steps), np.zeros(steps)], axis=1)
    return {"circle": (target, sensor, errors), "spiral": (0.5 * target, 0.5 * sensor, 2.0 * errors)}


def test_the_figure_has_paths_error_along_the_path_and_error_over_time(tmp_path, monkeypatch):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from simshear_gym import demo

    saved = {}
    monkeypatch.setattr(plt.Figure, "savefig", lambda self, path, **kw: saved.update(figure=self, path=Path(path)))
    monkeypatch.setattr(plt, "close", lambda figure=None: None)
    runs = synthetic_runs()
    demo.figure(runs, tmp_path / "tracking.png", "title", period_s=0.1)
    figure = saved["figure"]
    titles = [axis.get_title() for axis in figure.axes]
    assert titles[0].startswith("circle\nerror 0.25 mm (max 0.30)") and titles[3].startswith("spiral\nerror 0.50 mm")
    assert titles.count("error along the path (from above)") == 2
    over_time = [axis for axis in figure.axes if axis.get_xlabel() == "time s"]
    assert len(over_time) == 2 and all(axis.get_ylabel() == "contact error mm" for axis in over_time)
    line = over_time[0].get_lines()[0]
    assert np.allclose(line.get_xdata(), 0.1 * np.arange(1, 41)) and np.allclose(line.get_ydata(), runs["circle"][2])
    along = [axis for axis in figure.axes if axis.get_title().startswith("error along")][1]
    dots = along.collections[0]
    assert np.allclose(dots.get_array(), runs["spiral"][2])
    assert dots.get_clim() == (0.0, runs["spiral"][2].max())  # one colour scale for every run: the largest error
    colourbars = [axis for axis in figure.axes if axis.get_label() == "<colorbar>"]
    assert [axis.get_ylabel() for axis in colourbars] == ["contact error mm"]


@pytest.mark.slow
def test_the_demo_runs_and_writes_its_figure(tmp_path, capsys):
    from simshear_gym.cli import main

    assert main(["demo", "--trajectories", "circle", "--max-steps", "5", "--out", str(tmp_path)]) == 0
    assert (tmp_path / "tracking.png").stat().st_size > 10_000
    assert "circle" in capsys.readouterr().out
