"""Every agent in the full-size class: actions finite and in bounds on a full-size track, the
follower's feed-forward against the class's drag, alpha and PPO refusing a track of another
class, a vehicle of another class than the track's refused, the ORCA path unchanged."""

from __future__ import annotations

import numpy as np
import pytest

from agents import make_agent_spec
from racing_env.controllers import RacelineFollower, follower_action, understeer_gradient
from racing_env.tracks import make_track
from racing_env.vehicle import VehicleParams
from racing_env.vehicles import FullSizeParams, track_class, vehicle_for_track
from racing_env.vehicles.fullsize import n_substeps_fullsize, rk4_fullsize

MONZA = "tumftm:Monza"


@pytest.fixture(scope="module")
def monza():
    """Monza at full size, marked as a full-size track (``Track.vehicle_class``; set here
    until ``make_track(..., vehicle_class="fullsize")`` sets it itself)."""
    track = make_track(MONZA, vehicle_class="fullsize")
    if track_class(track) != "fullsize":
        object.__setattr__(track, "vehicle_class", "fullsize")
    return track


def _obs(x: np.ndarray, length: float, n_preview: int = 10) -> np.ndarray:
    obs = np.concatenate([x, np.zeros(n_preview)]).astype(np.float32)
    obs[0] = x[0] % length
    return obs


def _drive(agent, track, steps: int, v0: float = 30.0):
    """Drive ``agent`` alone from the racing line at ``v0`` for ``steps`` periods of 0.1 s in
    the full-size model; the actions and the final state."""
    v = FullSizeParams()
    p = v.pack()
    x = np.zeros(6)
    x[3] = v0
    actions = []
    for _ in range(steps):
        a = agent.act(_obs(x, track.length))
        actions.append(a)
        kappa = float(np.interp(x[0] % track.length, track.s_grid, track.kappa))
        n_sub = n_substeps_fullsize(x[3], p, 0.1, 1.0, 100)
        rk4_fullsize(x, float(a[0]), float(a[1]) * v.delta_max, kappa, p, 0.1, n_sub)
    return np.array(actions), x


def test_vehicle_for_track(monza):
    assert isinstance(vehicle_for_track(monza), FullSizeParams)
    assert isinstance(vehicle_for_track(make_track("default")), VehicleParams)
    with pytest.raises(ValueError, match=r"'orca' class, but track 'Monza' is sized for the "):
        vehicle_for_track(monza, VehicleParams(), "mpc")
    with pytest.raises(ValueError, match="'fullsize' class"):
        vehicle_for_track(make_track("default"), FullSizeParams(), "mpc")


@pytest.mark.parametrize("spec", ["raceline", "mpc", "mpc:space=extended,b=0.5", "mpc:zeta=1.0"])
def test_vehicle_mismatch_refused(monza, spec):
    from agents.mpc_agent import MPCAgent

    if spec.startswith("raceline"):
        agent = RacelineFollower(vehicle=VehicleParams())
    else:
        agent = make_agent_spec(spec)
        assert isinstance(agent, MPCAgent)
        agent.vehicle_given = VehicleParams()
    with pytest.raises(ValueError, match="'orca' class"):
        agent.reset(monza, "car_0", 0)


@pytest.mark.parametrize("spec", ["random", "constant:throttle=0.3,steering=-0.2", "raceline"])
def test_simple_agents_act_in_bounds(monza, spec):
    agent = make_agent_spec(spec)
    agent.reset(monza, "car_0", 0)
    actions, x = _drive(agent, monza, 20)
    assert np.isfinite(actions).all() and np.abs(actions).max() <= 1.0
    assert np.isfinite(x).all()


def test_follower_scaled_to_the_class(monza):
    f = RacelineFollower()
    f.reset(monza)
    assert isinstance(f.vehicle, FullSizeParams)
    assert f.preview_min == pytest.approx(0.5 * 4.7 / 0.12)
    assert f.yield_behind == pytest.approx(0.2 * 4.7 / 0.12)
    assert f.k_us == pytest.approx(understeer_gradient(FullSizeParams()))
    explicit = RacelineFollower(preview_min=0.7)
    explicit.reset(monza)
    assert explicit.preview_min == 0.7  # given: used as given
    assert len(f.gains()) == 13 + 13 + 25


def test_follower_feed_forward_holds_speed(monza):
    """On a straight at the profile's speed, the throttle is the class's drag and rolling
    resistance over the power-limited drive, and holds the speed."""
    v = FullSizeParams()
    f = RacelineFollower()
    f.reset(monza)
    M = len(monza.s_grid)
    for speed in (30.0, 45.0, 60.0):  # below the top speed (66 m/s)
        tables = (np.zeros(M), np.zeros(M), np.zeros(M), np.full(M, speed))
        x = np.array([100.0, 0.0, 0.0, speed, 0.0, 0.0])
        d, steer = follower_action(x, *tables, monza.ds, monza.length, f.gains())
        drive = min(v.F_drive_max, v.P_max / np.hypot(speed, v.v_low))
        want = (v.c_drag * speed**2 + v.c_roll * v.m * v.g) / drive
        assert d == pytest.approx(want, rel=1e-12)
        assert steer == 0.0
        y = x.copy()
        p = v.pack()
        for _ in range(10):  # one second on a straight: the speed stays within 0.1%
            rk4_fullsize(y, d, 0.0, 0.0, p, 0.1, n_substeps_fullsize(y[3], p, 0.1, 1.0, 100))
        assert y[3] == pytest.approx(speed, rel=1e-3)


def test_follower_orca_gains_unchanged():
    f = RacelineFollower()
    f.reset("default")
    v = VehicleParams()
    g = f.gains()
    assert len(g) == 13
    assert list(g[6:10]) == [v.C1, v.C2, v.C3, v.C4]
    assert f.preview_min == 0.5 and f.yield_behind == 0.2


@pytest.mark.parametrize("spec", ["mpc", "mpc:zeta=1.0,space=extended,b=0.3", "ibr"])
def test_mpc_family_acts_in_bounds(monza, spec):
    agent = make_agent_spec(spec)
    agent.reset(monza, "car_0", 0)
    actions, x = _drive(agent, monza, 15)
    assert np.isfinite(actions).all() and np.abs(actions).max() <= 1.0
    assert np.isfinite(x).all() and x[3] > 20.0  # keeps going


def test_mpc_two_cars_full_size(monza):
    """With a car just ahead, the reference's shifts and separations in the class's metres."""
    agent = make_agent_spec("mpc:s1=0.2,s2=4.0,s3=1.0")
    agent.reset(monza, "car_0", 0)
    ego = np.array([100.0, 0.0, 0.0, 40.0, 0.0, 0.0])
    other = np.array([130.0, 0.5, 0.0, 35.0, 0.0, 0.0])
    obs = np.concatenate([ego, other - ego, np.zeros(10)]).astype(np.float32)
    a = agent.act(obs)
    assert np.isfinite(a).all() and np.abs(a).max() <= 1.0
    assert agent.mpc.cfg.sep_s == pytest.approx(0.15 * 4.7 / 0.12)


def test_mpc_config_scaled():
    from agents.mpc import MPCConfig
    from agents.mpc.config import config_for_vehicle

    cfg = MPCConfig()
    assert config_for_vehicle(cfg, VehicleParams()) is cfg
    big = config_for_vehicle(cfg, FullSizeParams())
    assert big.track_margin == pytest.approx(0.03 * 2.0 / 0.06)
    assert big.sep_window == pytest.approx(2.0 * 4.7 / 0.12)
    assert big.horizon == cfg.horizon and big.dt == cfg.dt


def test_alpha_refuses_other_class(monza):
    agent = make_agent_spec("alpha")
    with pytest.raises(ValueError, match=r"trained for the 'orca' vehicle class; track 'Monza'"):
        agent.reset(monza, "car_0", 0)
    auto = make_agent_spec("alpha:model=auto")
    with pytest.raises(ValueError, match="'fullsize' class"):
        auto.reset(monza, "car_0", 0)
    # the message names the shipped model of the track's class, and that one races there
    with pytest.raises(ValueError, match="Race alpha:model=fullsize_monza, train a model"):
        agent.reset(monza, "car_0", 0)
    make_agent_spec("alpha:model=fullsize_monza").reset(monza, "car_0", 0)


def test_ppo_refuses_other_class(monza):
    """A named checkpoint of one class refuses a track of the other (``ppo`` without one
    races the track's class's shipped policy instead: tests/test_ppo_fullsize.py)."""
    pytest.importorskip("stable_baselines3")
    from agents.ppo_agent import default_checkpoint

    agent = make_agent_spec(f"ppo:checkpoint={default_checkpoint('orca')}")
    assert agent.vehicle_class == "orca"
    with pytest.raises(ValueError, match=r"'orca' vehicle class; track 'Monza' is sized for"):
        agent.reset(monza, "car_0", 0)
    agent.reset("default", "car_0", 0)  # its own class: fine


def _solo(spec: str, steps: int, track=None):
    """The env core after ``spec`` drove alone from the grid of a full-size circuit (default
    Monza) for ``steps`` control periods (seed 0)."""
    from racing_env import RacingParallelEnv

    env = RacingParallelEnv(
        track=track or MONZA, n_cars=1, max_cycles=steps, start="grid", vehicle_class="fullsize"
    )
    obs, _ = env.reset(seed=0)
    agent = make_agent_spec(spec)
    agent.reset(env.track, "car_0", 0)
    while env.agents:
        obs, *_ = env.step({"car_0": agent.act(obs["car_0"])})
    return env.core


@pytest.mark.slow
def test_mpc_solo_lap_full_size_monza():
    """The MPC at zeta 1 alone on full-size Monza from the grid (320 s, about 2 min): no
    off-track step, and its second (flying) lap near the racing line's estimate. Measured
    +4.7% (146.6 s against 140.0 s, slip-bounded): the issue's goal is 3%, not reached yet
    (the losses are at the exits of Roggia, Lesmo and Ascari, docs "Solo laps"); the bound
    keeps what is reached."""
    from racing_env.controllers import raceline_config_for
    from racing_env.raceline import get_raceline

    core = _solo("mpc:zeta=1.0", 3200)
    laps = np.diff([0.0, *core.lap_times[0][0]])
    v = FullSizeParams()
    est = get_raceline(
        make_track(MONZA, vehicle_class="fullsize"), v, raceline_config_for(v)
    ).lap_time
    assert int(core.offtracks[0][0]) == 0
    assert len(laps) >= 2
    assert laps[1] / est - 1.0 < 0.06


def test_follower_and_line_lengths_as_scaling():
    """The follower scales its lengths and the racing line's itself (racing_env.scaling reads
    the follower's defaults, so the follower cannot import it): the same as scaled_configs."""
    from dataclasses import replace

    from racing_env import controllers
    from racing_env.scaling import SCALED_FIELDS, scaled_configs

    assert controllers._FOLLOWER_LENGTHS == SCALED_FIELDS["RacelineFollower"]
    assert controllers._RACELINE_LENGTHS == SCALED_FIELDS["RacelineConfig"]
    v = FullSizeParams()
    scaled = scaled_configs(v)
    for objective in ("curvature", "lap_time"):
        want = replace(scaled.raceline, objective=objective)
        assert controllers.raceline_config_for(v, objective) == want
    f = RacelineFollower()
    f.reset(make_track(MONZA, vehicle_class="fullsize"))
    for name, value in scaled.follower.items():
        assert getattr(f, name) == pytest.approx(value, rel=1e-15)


def test_friction_ellipse_room_by_hand():
    """The full-size throttle limits leave each axle what its friction ellipse has left along
    the car: at a lateral acceleration whose share on an axle (front l_r / L, rear l_f / L of
    m a_y) is 60% of its peak, 80% (sqrt(1 - 0.36)) of the peak; the floor where the corner
    takes it all; the straight-line limits at yaw rate 0."""
    from agents.mpc.prediction import MPC_GRIP_USE, throttle_limits
    from racing_env.controllers import FULLSIZE_LONG_FLOOR, _fullsize_long_room

    v = FullSizeParams()
    p = v.pack()
    vx = 30.0
    d_f, d_r = v.axle_grip(vx)
    a_y = 0.6 * d_r * v.wheelbase / (v.m * v.lf)  # the rear's share: 60% of its peak
    r_f, r_r = _fullsize_long_room(a_y, d_f, d_r, p)
    assert r_r == pytest.approx(0.8, rel=1e-12)
    u_f = v.m * a_y * v.lr / v.wheelbase / d_f
    assert r_f == pytest.approx(np.sqrt(1 - u_f**2), rel=1e-12)
    assert _fullsize_long_room(2.0 * a_y, d_f, d_r, p) == (FULLSIZE_LONG_FLOOR,) * 2
    drive = min(v.F_drive_max, v.P_max / np.hypot(vx, v.v_low))
    brake = v.F_brake_max * np.tanh(vx / v.v_low)
    lo0, hi0 = throttle_limits(v, vx)
    assert hi0 == pytest.approx(min(MPC_GRIP_USE[0] * d_r / drive, 1.0), rel=1e-12)
    want_lo = -MPC_GRIP_USE[1] * min(d_f / v.k_brake_front, d_r / (1 - v.k_brake_front)) / brake
    assert lo0 == pytest.approx(max(want_lo, -1.0), rel=1e-12)
    lo, hi = throttle_limits(v, vx, omega=a_y / vx)  # the same corner, from the yaw rate
    assert hi == pytest.approx(MPC_GRIP_USE[0] * 0.8 * d_r / drive, rel=1e-12)
    want_lo = -MPC_GRIP_USE[1] * min(r_f * d_f / v.k_brake_front, 0.8 * d_r / 0.4) / brake
    assert lo == pytest.approx(want_lo, rel=1e-12)
    assert throttle_limits(v, vx, omega=-a_y / vx) == (lo, hi)  # either way round


def test_follower_traction_control_on_the_ellipse(monza):
    """The follower's drive on a straight asks FULLSIZE_GRIP_USE[0] of the rear's peak; on a
    line whose curvature asks more than the rear's peak across, only the floor's share."""
    from racing_env.controllers import FULLSIZE_GRIP_USE, FULLSIZE_LONG_FLOOR

    v = FullSizeParams()
    f = RacelineFollower()
    f.reset(monza)
    M = len(monza.s_grid)
    vx = 25.0
    tables = (np.zeros(M), np.zeros(M), np.zeros(M), np.full(M, 60.0))  # far below: full drive
    drive = min(v.F_drive_max, v.P_max / np.hypot(vx, v.v_low))
    d_r = v.axle_grip(vx)[1]
    x = np.array([100.0, 0.0, 0.0, vx, 0.0, 0.0])
    d, _ = follower_action(x, *tables, monza.ds, monza.length, f.gains())
    assert d == pytest.approx(FULLSIZE_GRIP_USE[0] * d_r / drive, rel=1e-12)
    kappa = 1.1 * d_r * v.wheelbase / (v.m * v.lf) / vx**2  # the rear's lateral force > peak
    tables = (tables[0], tables[1], np.full(M, kappa), tables[3])
    d, _ = follower_action(x, *tables, monza.ds, monza.length, f.gains())
    assert d == pytest.approx(FULLSIZE_GRIP_USE[0] * FULLSIZE_LONG_FLOOR * d_r / drive, rel=1e-12)


def test_follower_full_size_steering_law(monza):
    """The full-size follower's own law (FULLSIZE_STEER), by hand: the preview max(6 m, 0.7 s
    vx) on a lateral error, the heading error's gain k_mu / D, the yaw-rate damping k_yaw L
    (vx kappa_cmd - omega) / vx, and the drive fading from slip_onset of the rear's peak slip
    angle to nothing at the peak."""
    from racing_env.controllers import FULLSIZE_GRIP_USE, FULLSIZE_STEER

    v = FullSizeParams()
    floor, t_prev, k_yaw, onset, _, k_mu = FULLSIZE_STEER
    f = RacelineFollower()
    f.reset(monza)
    M = len(monza.s_grid)
    L = v.lf + v.lr
    for vx in (5.0, 30.0):  # the floor, then the time
        D = max(floor, t_prev * vx)
        tables = (np.full(M, 0.5), np.zeros(M), np.zeros(M), np.full(M, vx))
        x = np.array([100.0, 0.0, 0.0, vx, 0.0, 0.0])
        _, steer = follower_action(x, *tables, monza.ds, monza.length, f.gains())
        k = 0.5 / D**2  # the lateral error's curvature; no yaw-rate error but vx k
        delta = np.arctan(L * k) + f.k_us * vx**2 * k + k_yaw * L * (vx * k) / vx
        assert steer == pytest.approx(delta / v.delta_max, rel=1e-12)
    # a heading error on a straight: the curvature k_mu / D times it
    vx = 30.0
    D = t_prev * vx
    tables = (np.zeros(M), np.full(M, 0.02), np.zeros(M), np.full(M, vx))
    x = np.array([100.0, 0.0, 0.0, vx, 0.0, 0.0])
    _, steer = follower_action(x, *tables, monza.ds, monza.length, f.gains())
    k = k_mu / D * 0.02
    delta = np.arctan(L * k) + f.k_us * vx**2 * k + k_yaw * L * (vx * k) / vx
    assert steer == pytest.approx(delta / v.delta_max, rel=1e-12)
    # a yaw rate on a straight: counter-steered, k_yaw L omega / vx
    tables = (np.zeros(M), np.zeros(M), np.zeros(M), np.full(M, 30.0))
    x = np.array([100.0, 0.0, 0.0, 30.0, 0.0, 0.1])
    _, steer = follower_action(x, *tables, monza.ds, monza.length, f.gains())
    assert steer == pytest.approx(-k_yaw * L * 0.1 / 30.0 / v.delta_max, rel=1e-12)
    # the traction rule: the rear sliding at 65% of its peak slip angle halves the drive
    vx = 25.0
    alpha_peak = np.tan(0.5 * np.pi / v.C_r) / v.B_r
    alpha = onset + 0.5 * (1.0 - onset)
    tables = (np.zeros(M), np.zeros(M), np.zeros(M), np.full(M, 60.0))
    x = np.array([100.0, 0.0, 0.0, vx, -vx * np.tan(alpha * alpha_peak), 0.0])
    d, _ = follower_action(x, *tables, monza.ds, monza.length, f.gains())
    drive = min(v.F_drive_max, v.P_max / np.hypot(vx, v.v_low))
    assert d == pytest.approx(0.5 * FULLSIZE_GRIP_USE[0] * v.axle_grip(vx)[1] / drive, rel=1e-9)


@pytest.mark.slow
def test_follower_laps_full_size_monza():
    """The raceline follower alone on full-size Monza from the grid (a standing start, 170
    s): one lap without leaving the track (measured 158.4 s; the ORCA law's preview cut the
    first chicane)."""

    core = _solo("raceline", 1700)
    assert int(core.offtracks[0][0]) == 0
    assert len(core.lap_times[0][0]) >= 1


def test_mpc_leaves_silverstone_grid():
    """From Silverstone's grid the full-size MPC's first solve failed (the QP's iteration
    limit) and the fallback lifted the throttle to 0 at every step: the car never moved. A
    failed solve with the car stopped now drives the follower's rollout."""

    core = _solo("mpc:zeta=1.0", 30, "tumftm:Silverstone")
    assert float(core.state[0, 0, 3]) > 5.0
    assert int(core.offtracks[0][0]) == 0
