"""The race's record of the thetas driven, and its plot (``thetas.png`` of ``alpha-racer race``)."""

import numpy as np
import pytest

from experiments.evaluation.race import RaceResult, write_outputs
from experiments.evaluation.theta_plot import plot_thetas, varying_cars


def _result(thetas, names, T=40, n=3):
    """A made-up 3-car race: car 1 starts 0.5 m behind car 0, gains and passes it clear
    sideways at about 2 s; car 2 trails."""
    t = np.arange(T + 1) * 0.1
    st = np.zeros((T + 1, n, 6))
    st[:, 0, 0] = 3.0 * t
    st[:, 1, 0] = 3.0 * t - 0.5 + 0.5 * t
    st[:, 1, 1] = 0.12
    st[:, 2, 0] = 2.8 * t - 1.0
    return RaceResult(
        agents=["mpc", "alpha", "raceline"],
        track="default",
        seed=0,
        dt=0.1,
        states=st,
        progress=st[-1, :, 0] - st[0, :, 0],
        lap_times=[[], [], []],
        contacts=np.zeros(n, int),
        off_tracks=np.zeros(n, int),
        decision_ms=np.ones(n),
        env_step_ms=1.0,
        thetas=thetas,
        theta_names=names,
    )


PAPER = ["q", "zeta", "s1", "s2", "s3"]


def test_only_cars_whose_theta_changed_are_plotted(tmp_path):
    fixed = np.tile([5.0, 1.05, 0.3, 0.5, 0.0], (40, 1))
    chosen = fixed.copy()
    chosen[20:, 4] = 5.0  # blocks after its pass
    r = _result([fixed, chosen, None], [PAPER, PAPER, None])
    assert varying_cars(r.thetas) == [1]
    assert r.metrics["pass_events"][0]["passer"] == 1
    path = plot_thetas(r, tmp_path / "thetas.png")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    paths = write_outputs(r, [], tmp_path / "race")
    assert paths["thetas"].exists()


def test_a_race_without_a_chosen_theta_writes_no_theta_plot_and_bad_input_is_named(tmp_path):
    fixed = np.tile([5.0, 1.05, 0.3, 0.5, 0.0], (40, 1))
    r = _result([fixed, None, None], [PAPER, None, None])
    assert varying_cars(r.thetas) == []
    assert "thetas" not in write_outputs(r, [], tmp_path / "race")
    with pytest.raises(ValueError, match="no car's theta changed"):
        plot_thetas(r, tmp_path / "t.png")
    with pytest.raises(ValueError, match=r"writes PNG; got suffix '.jpg'"):
        plot_thetas(r, tmp_path / "t.jpg")
