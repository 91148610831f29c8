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

from .codegen import load_prediction
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


def stage_function(vehicle: VehicleParams, cfg: MPCConfig, jacobians: bool = True) -> Any:
    """CasADi ``stage(x[6], u[2], kap[substeps]) -> (x_next, vec(dx_next/dx), vec(dx_next/du))``:
    one 0.1 s stage of ``substeps`` RK4 steps of the simulator's model (``frenet_ode``) with
    the prediction's ``v_low``; ``u`` are the env's normalised inputs. Without ``jacobians``
    it returns ``x_next`` only."""
    import casadi as ca

    from racing_env.vehicle import frenet_ode_casadi

    ode = frenet_ode_casadi()
    p = [float(v) for v in vehicle.pack()]
    x = ca.SX.sym("x", 6)
    u = ca.SX.sym("u", 2)
    kap = ca.SX.sym("kap", cfg.substeps)
    # decision variables are the env's normalised inputs in [-1, 1]^2 (so R = I weighs a full
    # throttle swing like a full steering swing); map them to physical (d, delta) here
    d_phys = 0.5 * (vehicle.d_max + vehicle.d_min) + 0.5 * (vehicle.d_max - vehicle.d_min) * u[0]
    delta_phys = vehicle.delta_max * u[1]

    def f(xx, kk):
        pp = list(p)
        pp[P_VLOW] = prediction_v_low(xx[3], vehicle.v_low, cfg, ca.exp)
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


def trajectory_function(
    vehicle: VehicleParams, cfg: MPCConfig, jacobians: bool = True
) -> CompiledTrajectory | InterpretedTrajectory:
    """The horizon ``(x0[6], U[2xK], KAP[substeps x K]) -> (X[6xK], A[36xK], B[12xK])`` (numpy
    arrays): the stage function folded K times (mapaccum), compiled to C and cached on disk
    by :func:`~agents.mpc.codegen.load_prediction` (interpreted by CasADi, with a warning, when
    no C compiler works). Without ``jacobians``: ``(X,)`` only, a rollout several times
    cheaper."""
    stage = stage_function(vehicle, cfg, jacobians)
    name = "mpc_traj" if jacobians else "mpc_roll"
    return load_prediction(stage.mapaccum(name, cfg.horizon), cfg.horizon, cfg.substeps, name)


def stage_nodes(s_nominal: np.ndarray | None, x0: np.ndarray, K: int, dt: float) -> np.ndarray:
    """Progress (K + 1,) at the stage boundaries to look curvature up at: the previous nominal
    (K + 1,) shifted by one stage and re-anchored at ``x0``, or, without one, constant speed."""
    if s_nominal is None:
        return x0[0] + max(float(x0[3]), 0.5) * dt * np.arange(K + 1)
    nodes = np.concatenate([s_nominal[1:], [2 * s_nominal[-1] - s_nominal[-2]]])
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
def _rollout(x, n_ref, mu_ref, kappa_ref, v_ref, kappa_tab, ds, length, gains, p, act_map, dt, U):
    """Roll the follower law forward from state ``x`` in the simulator's model; inputs into U."""
    for k in range(U.shape[1]):
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
    vehicle: VehicleParams,
    follower: RacelineFollower,
    x0: np.ndarray,
    K: int,
    dt: float,
) -> np.ndarray:
    """Normalised inputs (2, K) from rolling the raceline follower's law forward from ``x0``
    (6,) in the simulator's model for ``K`` stages of ``dt`` s: an on-track initial guess.
    ``follower`` is a :class:`racing_env.controllers.RacelineFollower` reset on ``track``."""
    U = np.empty((2, K))
    v = vehicle
    _rollout(
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
    )
    return U


def make_follower(
    track: Track, vehicle: VehicleParams, line: str = "curvature"
) -> RacelineFollower:
    """A raceline follower of racing line ``line`` reset on ``track`` (for
    :func:`follower_rollout`)."""
    from racing_env.controllers import RacelineFollower

    follower = RacelineFollower(vehicle, line=line)
    follower.reset(track)
    return follower
