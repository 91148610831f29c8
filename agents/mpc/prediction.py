"""The MPC's prediction: one stage of RK4 steps of the simulator's model (CasADi), folded over
the horizon and compiled (:func:`trajectory_function`, the rollout IBR uses too), the track
curvature along a plan's progress, and the raceline follower's rollout that warm-starts a
plan."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from numba import njit

from racing_env.controllers import follower_action
from racing_env.integrator import _n_substeps, integrate_car
from racing_env.interp import periodic_lookup as _lookup
from racing_env.track import Track
from racing_env.vehicle import P_VLOW, VehicleParams
from racing_env.vehicles import FullSizeParams
from racing_env.vehicles.fullsize import P_VLOW as P_VLOW_FULLSIZE

from .codegen import PredictionSpec, load_predictions
from .config import MPCConfig

if TYPE_CHECKING:
    from collections.abc import Callable
    from typing import Any

    from racing_env.controllers import RacelineFollower

    from .codegen import CompiledTrajectory, InterpretedTrajectory


def prediction_v_low(
    vx: Any, v_low_sim: float, cfg: MPCConfig, exp: Callable[[Any], Any] = np.exp
) -> Any:
    """Slip regularisation [m/s] of the prediction model at speed ``vx`` [m/s]:
    ``v_low_sim + (cfg.v_low - v_low_sim) exp(-(vx / cfg.v_blend)^2)``. Near rest the larger
    ``cfg.v_low`` keeps the RK4 sub-steps stable; at racing speed (within 1e-3 above
    ``2.7 v_blend``) it is the simulator's own, so the prediction holds the tyre forces the car
    really has (a constant 0.5 m/s cost 4% of lateral force at 2.5 m/s)."""
    return v_low_sim + (cfg.v_low - v_low_sim) * exp(-((vx / cfg.v_blend) ** 2))


def stage_function(
    vehicle: VehicleParams | FullSizeParams, cfg: MPCConfig, jacobians: bool = True
) -> Any:
    """CasADi ``stage(x[6], u[2], kap[substeps]) -> (x_next, vec(dx_next/dx), vec(dx_next/du))``:
    one 0.1 s stage of ``substeps`` RK4 steps of the simulator's model of the car's class
    (``frenet_ode``, or ``frenet_ode_fullsize`` in clean air: wake factors 1) with the
    prediction's ``v_low``; ``u`` are the env's normalised inputs. Without ``jacobians`` it
    returns ``x_next`` only."""
    import casadi as ca

    from racing_env.vehicle import frenet_ode_casadi
    from racing_env.vehicles.fullsize import frenet_ode_fullsize_casadi

    full = isinstance(vehicle, FullSizeParams)
    ode = frenet_ode_fullsize_casadi() if full else frenet_ode_casadi()
    i_vlow = P_VLOW_FULLSIZE if full else P_VLOW
    p = [float(v) for v in vehicle.pack()]
    x = ca.SX.sym("x", 6)
    u = ca.SX.sym("u", 2)
    kap = ca.SX.sym("kap", cfg.substeps)
    # decision variables are the env's normalised inputs in [-1, 1]^2 (so R = I weighs a full
    # throttle swing like a full steering swing); map them to physical (d, delta) here
    d_phys = 0.5 * (vehicle.d_max + vehicle.d_min) + 0.5 * (vehicle.d_max - vehicle.d_min) * u[0]
    delta_phys = vehicle.delta_max * u[1]
    if isinstance(vehicle, FullSizeParams):  # a share of its traction or brake limit
        d_phys = limited_throttle(vehicle, u[0], x[3], ca, x[5])

    def f(xx, kk):
        pp = list(p)
        pp[i_vlow] = prediction_v_low(xx[3], vehicle.v_low, cfg, ca.exp)
        return ca.vertcat(*ode(xx[1], xx[2], xx[3], xx[4], xx[5], d_phys, delta_phys, kk, pp))

    h = cfg.dt / cfg.substeps
    xn = x
    for j in range(cfg.substeps):
        k1 = f(xn, kap[j])
        k2 = f(xn + h / 2 * k1, kap[j])
        k3 = f(xn + h / 2 * k2, kap[j])
        k4 = f(xn + h * k3, kap[j])
        xn = xn + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    if not jacobians:
        return ca.Function("stage_x", [x, u, kap], [xn])
    return ca.Function(
        "stage",
        [x, u, kap],
        [xn, ca.densify(ca.vec(ca.jacobian(xn, x))), ca.densify(ca.vec(ca.jacobian(xn, u)))],
    )


#: shares ``(drive, brake)`` of what an axle's friction ellipse leaves along the car that the
#: full-size MPC asks of it (:func:`throttle_limits`). Above the follower's
#: :data:`racing_env.controllers.FULLSIZE_GRIP_USE`: the MPC predicts with the car's own
#: model, so it steers the car that a strong drive makes oversteer
MPC_GRIP_USE = (0.95, 0.97)
#: drive and brake shares of the raceline follower whose rollout warm-starts the full-size
#: MPC (:func:`make_follower`; the follower's shares before its own steering law)
WARM_START_GRIP_USE = (0.6, 0.9)


def throttle_limits(
    vehicle: FullSizeParams, vx: Any, backend: Any = np, omega: Any = 0.0
) -> tuple[Any, Any]:
    """Physical throttle bounds ``(d_lo, d_hi)`` of the full-size car at speed ``vx`` [m/s]:
    the drive asks at most :data:`MPC_GRIP_USE` ``[0]`` of what the rear axle's friction
    ellipse leaves along the car, the brakes at most ``[1]`` of either axle's, within
    ``[d_min, d_max]`` (beyond them the friction ellipse leaves the axle no lateral force and
    the car spins or goes straight on). The ellipse's room: at yaw rate ``omega`` [rad/s] the
    car corners at ``a_y = vx omega``, the front axle carrying ``l_r / L`` of ``m a_y``, the
    rear ``l_f / L``; an axle of peak ``D`` then has ``sqrt(1 - (F_y / D)^2)`` of it left
    along the car, at least :data:`racing_env.controllers.FULLSIZE_LONG_FLOOR` (the
    follower's rule; ``omega = 0``: the straight-line limits). ``backend``: numpy, math or
    casadi. The MPC's prediction applies them at each stage's start and :meth:`MPC.solve` to
    the input it returns, so the plan and the applied throttle agree."""
    from racing_env.controllers import FULLSIZE_LONG_FLOOR

    v = vehicle
    M = backend
    fmin = getattr(M, "fmin", None) or getattr(M, "minimum", None) or min
    fmax = getattr(M, "fmax", None) or getattr(M, "maximum", None) or max
    w = v.m * v.g / v.wheelbase
    q = vx * vx
    tf = 0.5 * (w * v.lr + v.c_lift_f * q)
    tr = 0.5 * (w * v.lf + v.c_lift_r * q)
    d_f = 2.0 * v.mu * tf * (1.0 + v.eps_f * (tf - v.Fz_shift) / v.Fz0)
    d_r = 2.0 * v.mu * tr * (1.0 + v.eps_r * (tr - v.Fz_shift) / v.Fz0)
    drive = fmin(v.F_drive_max, v.P_max / M.sqrt(q + v.v_low * v.v_low))
    a_y = vx * omega
    f_y = v.m * a_y / v.wheelbase
    floor = FULLSIZE_LONG_FLOOR * FULLSIZE_LONG_FLOOR
    d_f = d_f * M.sqrt(fmax(1.0 - (f_y * v.lr / d_f) ** 2, floor))
    d_r = d_r * M.sqrt(fmax(1.0 - (f_y * v.lf / d_r) ** 2, floor))
    hi = fmin(MPC_GRIP_USE[0] * d_r / drive, v.d_max)
    brake = fmax(v.F_brake_max * M.tanh(fmax(vx, 0.0) / v.v_low), 1e-9)
    lo = fmax(
        -MPC_GRIP_USE[1] * fmin(d_f / v.k_brake_front, d_r / (1.0 - v.k_brake_front)) / brake,
        v.d_min,
    )
    return lo, hi


def limited_throttle(
    vehicle: FullSizeParams, u: Any, vx: Any, backend: Any = np, omega: Any = 0.0
) -> Any:
    """The full-size car's physical throttle for the MPC's normalised throttle ``u`` in [-1, 1]
    at speed ``vx``: ``u`` times the traction limit ``d_hi`` when positive, times ``-d_lo``
    (the brake limit) when negative (:func:`throttle_limits`), so ``u = 1`` is the most drive
    the rear tyres take without the car spinning. A scale, not a clip: a clip's flat part has
    no gradient, and an SQP plan that strayed into it (measured: braking at -1 where -0.38
    binds) could never come back. The prediction applies it at each stage's start and
    :meth:`MPC.solve` to the input it returns, so the plan and the applied throttle agree."""
    lo, hi = throttle_limits(vehicle, vx, backend, omega)
    return 0.5 * (u + backend.fabs(u)) * hi - 0.5 * (u - backend.fabs(u)) * lo


def trajectory_function(
    vehicle: VehicleParams | FullSizeParams, cfg: MPCConfig, jacobians: bool = True
) -> CompiledTrajectory | InterpretedTrajectory:
    """The horizon ``(x0[6], U[2xK], KAP[substeps x K]) -> (X[6xK], A[36xK], B[12xK])`` (numpy
    arrays): the stage function folded K times (mapaccum), compiled to C and cached on disk
    by :func:`~agents.mpc.codegen.load_prediction` (interpreted by CasADi, with a warning, when
    no C compiler works). Without ``jacobians``: ``(X,)`` only, a rollout several times
    cheaper. The compiled library's name includes the vehicle class (besides the hash of
    its code, which includes the parameters): ``mpc_traj_fullsize_<hash>.so``."""
    return load_predictions([_prediction_spec(vehicle, cfg, jacobians)])[0]


def trajectory_functions(
    vehicle: VehicleParams | FullSizeParams, cfg: MPCConfig
) -> tuple[CompiledTrajectory | InterpretedTrajectory, CompiledTrajectory | InterpretedTrajectory]:
    """``(trajectory_function(vehicle, cfg), trajectory_function(vehicle, cfg, False))``, the
    MPC's prediction with its jacobians and its rollout, compiled at the same time (one
    compiler process each, :func:`~agents.mpc.codegen.load_predictions`)."""
    key = (vehicle, cfg)
    if key not in _SPECS:  # the CasADi graphs are built once per process
        _SPECS[key] = [_prediction_spec(vehicle, cfg, True), _prediction_spec(vehicle, cfg, False)]
    full, states = load_predictions(_SPECS[key])
    return full, states


#: the prediction specs by (vehicle, config): an MPC per car and race would otherwise rebuild
#: and regenerate the same graphs (70 ms per MPC, 12% of a collection race)
_SPECS: dict[tuple, list[PredictionSpec]] = {}


def _prediction_spec(
    vehicle: VehicleParams | FullSizeParams, cfg: MPCConfig, jacobians: bool
) -> PredictionSpec:
    stage = stage_function(vehicle, cfg, jacobians)
    name = "mpc_traj" if jacobians else "mpc_roll"
    if isinstance(vehicle, FullSizeParams):
        name += "_fullsize"
    return PredictionSpec(stage.mapaccum(name, cfg.horizon), cfg.horizon, cfg.substeps, name)


def stage_nodes(s_nominal: np.ndarray | None, x0: np.ndarray, K: int, dt: float) -> np.ndarray:
    """Progress (K + 1,) at the stage boundaries to look curvature up at: the previous nominal
    (K + 1,) shifted by one stage and re-anchored at ``x0``, or, without one, constant speed
    (:func:`stage_nodes_of`)."""
    has_nom = s_nominal is not None
    nominal = np.asarray(s_nominal, dtype=float) if has_nom else np.zeros(K + 1)
    return stage_nodes_of(nominal, has_nom, np.asarray(x0, dtype=float), K, dt)


@njit(cache=True, nogil=True)
def stage_nodes_of(s_nominal, has_nom, x0, K, dt):
    """:func:`stage_nodes` in compiled code: ``s_nominal`` (K + 1,) read only if ``has_nom``."""
    if not has_nom:
        return x0[0] + max(x0[3], 0.5) * dt * np.arange(K + 1)
    nodes = np.empty(K + 1)
    for k in range(K):
        nodes[k] = s_nominal[k + 1]
    nodes[K] = 2 * s_nominal[-1] - s_nominal[-2]
    return nodes - nodes[0] + x0[0]


def kappa_at_substeps(track: Track, s_nodes: np.ndarray, substeps: int) -> np.ndarray:
    """Track curvature (substeps, K) at the start of every RK4 sub-step between the stage
    boundaries ``s_nodes`` (K + 1,) (progress interpolated linearly within a stage)."""
    s_nodes = np.asarray(s_nodes, dtype=float)
    flat = kappa_flat(track.kappa, s_nodes, substeps, track.ds, track.length)
    return np.ascontiguousarray(flat.reshape(s_nodes.shape[0] - 1, substeps).T)


@njit(cache=True)
def kappa_flat(table, s_nodes, m, ds, length):
    """:func:`kappa_at_substeps` laid out stage after stage (substeps K,), the layout of the
    compiled prediction's buffer."""
    K = s_nodes.shape[0] - 1
    out = np.empty(m * K)
    for k in range(K):
        step = s_nodes[k + 1] - s_nodes[k]
        for i in range(m):
            out[k * m + i] = _lookup(table, s_nodes[k] + step * i / m, ds, length)
    return out


@njit(cache=True)
def _rollout(
    x, n_ref, mu_ref, kappa_ref, v_ref, kappa_tab, ds, length, gains, p, act_map, dt, U, V
):
    """Roll the follower law forward from state ``x`` in the simulator's model (either class:
    :func:`racing_env.integrator.integrate_car` dispatches on ``p``, clean air); inputs into U,
    the speed at each stage's start into V."""
    for k in range(U.shape[1]):
        V[k] = x[3]
        a0, a1 = follower_action(x, n_ref, mu_ref, kappa_ref, v_ref, ds, length, gains)
        U[0, k] = a0
        U[1, k] = a1
        integrate_car(
            x,
            act_map[0] + act_map[1] * a0,
            act_map[2] * a1,
            kappa_tab,
            ds,
            length,
            p,
            dt,
            _n_substeps(x[3], p, dt, 1.0, 100),
        )


def follower_rollout(
    track: Track,
    vehicle: VehicleParams | FullSizeParams,
    follower: RacelineFollower,
    x0: np.ndarray,
    K: int,
    dt: float,
) -> np.ndarray:
    """Normalised inputs (2, K) from rolling the raceline follower's law forward from ``x0``
    (6,) in the simulator's model for ``K`` stages of ``dt`` s: an on-track initial guess.
    ``follower`` is a :class:`racing_env.controllers.RacelineFollower` reset on ``track``."""
    U, V = np.empty((2, K)), np.empty(K)
    v = vehicle
    args = (
        np.array(x0, dtype=float),
        *follower.tables(),
        track.kappa,
        track.ds,
        track.length,
        follower.gains(),
        v.pack(),
        np.array([0.5 * (v.d_max + v.d_min), 0.5 * (v.d_max - v.d_min), v.delta_max]),
        dt,
        U,
        V,
    )
    _rollout(*args)
    if not isinstance(v, FullSizeParams):
        return U
    # the MPC's throttle is a share of the traction / brake limit (limited_throttle)
    lo, hi = throttle_limits(v, V)
    d = 0.5 * (v.d_max + v.d_min) + 0.5 * (v.d_max - v.d_min) * U[0]
    U[0] = np.clip(np.where(d >= 0.0, d / hi, -d / lo), -1.0, 1.0)
    return U


def make_follower(
    track: Track, vehicle: VehicleParams | FullSizeParams, line: str = "curvature"
) -> RacelineFollower:
    """A raceline follower of racing line ``line`` reset on ``track`` (for
    :func:`follower_rollout`)."""
    from racing_env.controllers import RacelineFollower

    follower = RacelineFollower(vehicle, line=line)
    follower.reset(track)
    if isinstance(follower.vehicle, FullSizeParams):
        # the MPC's warm start keeps the ORCA law scaled to the class (the follower's own
        # law, with its preview, yaw damping, traction rule and 90% drive, left the MPC's
        # closed loop off the track on Monza: 108 off-track steps where it had none)
        follower.fullsize_law = (
            WARM_START_GRIP_USE,
            (follower.preview_min, follower.preview_time, 0.0, 1.0, follower.speed_preview, 2.0),
        )
        follower._gains = follower.gains()
    return follower
