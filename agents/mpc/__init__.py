"""The paper's MPC (equation 2) as a real-time iteration (RTI) SQP.

At every call: simulate the horizon with the shifted previous inputs (single shooting,
``K`` stages of ``substeps`` RK4 steps of the *same* model code as the simulator, evaluated
symbolically by CasADi and compiled to C), take the stage sensitivities ``A_k, B_k``, condense
them into ``d(s, n)^k / d u``, and solve one dense QP in the input corrections (2K
variables) with DAQP:

    min  q sum_{k=1..K} ||(s^k, n^k) - (s_ref^k, n_ref^k)||^2
         + sum_{k=1..K-1} ||u^k - u^{k-1}||^2                      (R = I)
    s.t. d_min <= d^k <= d_max, |delta^k| <= delta_max             (k = 0..K-1)
         |delta^k - delta^{k-1}| <= delta_rate_max dt               (k = 0..K-1, delta^{-1} applied)
         -w_right + margin <= n^k <= w_left - margin                (k = 1..K, soft)
         separation from the cars just ahead / behind               (k = 1..K, soft)

The tracking sum runs over the predicted states 1..K: the first state after the current one
through the last (the authors' code compared the current state with the first reference
point and never penalised the last). The paper lists the lateral *and* the longitudinal
separation as constraints; both at once would forbid ever being beside or behind another car,
so per stage and opponent we impose the one that the nominal prediction satisfies with the
larger margin, on the side where it is (the usual convexification of "not overlapping").
Opponents move at constant progress rate and lateral position (paper). Soft constraints
use DAQP's soft rows, a *quadratic* penalty: a violation ``v`` of a soft row costs
``v^2 / (2 rho)`` (in the units of the cost above), so the QP is always feasible. The weight
grows with the tracking gain above ``soft_q_ref`` (``rho = soft_rho * min(1, soft_q_ref / q)``,
:meth:`MPCConfig.soft_rho_at`): with a fixed rho a tight tracker (q = 500) traded 10 cm off
the track for 30 cm of tracking error and left the track on 22% of a 64-theta solo sweep of
``default``; scaled, the trade stays the one of q = 20 at every q.

Each QP step is checked on the nonlinear model (a merit test): the rollout of the new inputs
must lower the cost (tracking, input rates and the same quadratic penalty of the soft rows,
:func:`plan_cost`) below the current plan's, trying the full step and then shorter ones
(``step_sizes``, down to 1/8); a step that lowers nothing is rejected and the current plan
kept. An accepted step is linearised again, so the SQP iterates until a QP step promises
(:func:`predicted_decrease`) less than ``merit_rtol`` (0.1%) of the cost, no step length
lowers it, or ``sqp_iterations`` (12) QPs are spent; at the limit one linearisation of the car
over 1.5 s is poor, and a single QP step left plans up to 360x IPOPT's optimum of the same
problem. The first solve after a reset, and any solve whose shifted plan leaves the track or
whose car is nearly stopped, also rolls out the raceline follower's law and starts from
whichever plan costs less (a *restart*, counted in ``stats``). A failed QP or a non-finite
prediction falls back to the shifted previous plan with the throttle lifted (counted in
``stats``).

The curvature is a parameter of the compiled prediction, looked up at the stage progress of
a guess (the previous plan). Every plan is therefore rolled out again with the curvature
along its own progress (``curvature_passes``), and a trial step with the curvature along its
own linearised progress: scored along another plan's progress, a step that changes the speed
is judged on the wrong corner, and the merit test rejected the steps that would have fixed
the plan. Together these bring the RTI's plans within 5% of IPOPT's optimum in about 90% of
the states of a race at the limit (24-36% before; ``benchmarks/mpc_speed.py``).

The prediction model uses a larger low-speed slip regularisation (``v_low``, default 0.5 m/s)
than the simulator so that the RK4 sub-steps of a 0.1 s stage stay stable at a standing
start; above about 2 m/s the two models agree to a few percent. The QP's matrices are built
in one compiled pass (:func:`linearised_qp`); DAQP's iterations are capped (``qp_iter_limit``),
since a rare cycling QP otherwise spends 10k iterations before giving up. The rest of an SQP
iteration (the trial steps' rollouts and merit checks, the new linearisation) is one numba
call that calls the compiled predictions itself (:func:`sqp_step`, :mod:`.sqp_step`); with an
interpreted prediction the same step runs in Python. Both do the same arithmetic, so the
plans are the same bit for bit. With the fused helpers (:func:`trial_step`,
:func:`score_rollout`, :func:`linearised_qp`) a race of MPC cars takes about 20% less time
than with the separate numpy and ctypes calls before them; the kernel's own share is about
6% (``benchmarks/sqp_step.py``: 0.90 against 0.96 ms per decision on the collection's races).

The whole solve (warm start, restart, SQP loop with DAQP's C solver, fallback) also runs as
one compiled call (:mod:`.compiled_solve`) where the MPC is the paper's (ORCA car, no damped
steps, no second start): the same plans bit for bit, 1.3x faster per decision, and the
MPC steps of many cars (a lockstep batch: ``MPCAgent.act_group``) in one call, split over
threads (:func:`.compiled_solve.solve_many`). The full-size MPC and ``plan=damped`` solve from Python.

Modules, one job each: :mod:`.config` (:class:`MPCConfig`), :mod:`.codegen` (the prediction
as C: generated, compiled, cached, called from Python and numba), :mod:`.prediction` (the
model's stage and horizon, curvature along a plan, the follower's warm start), :mod:`.qp` (the
cost of a plan and its condensed QP), :mod:`.solver` (:class:`MPC` and the SQP step),
:mod:`.compiled_solve` (the solve in one compiled call), :mod:`.daqp_native` (DAQP from
compiled code).
"""

from collections.abc import Iterator
from contextlib import contextmanager

from . import compiled_solve
from .config import PLANS, MPCConfig
from .prediction import (
    follower_rollout,
    kappa_at_substeps,
    kappa_flat,
    make_follower,
    prediction_v_low,
    stage_function,
    stage_nodes,
    trajectory_function,
)
from .qp import (
    EdgeBounds,
    ProblemConstants,
    _grid_interp,  # noqa: F401  agents.mpc_agent's import
    condense,
    condense_states,
    input_rate_matrix,
    linearised_qp,
    opponent_paths,
    plan_cost,
    predicted_decrease,
    qp_arrays,
    score_rollout,
    separation_choice,
)
from .solver import MPC
from .sqp_step import StepCode, StepConstants, StepResult, sqp_step, trial_step

__all__ = [
    "compiled_solve",
    "stepwise_solves",
    "MPC",
    "EdgeBounds",
    "MPCConfig",
    "PLANS",
    "ProblemConstants",
    "StepCode",
    "StepConstants",
    "StepResult",
    "condense",
    "condense_states",
    "follower_rollout",
    "input_rate_matrix",
    "kappa_at_substeps",
    "kappa_flat",
    "linearised_qp",
    "make_follower",
    "opponent_paths",
    "plan_cost",
    "predicted_decrease",
    "prediction_v_low",
    "qp_arrays",
    "score_rollout",
    "separation_choice",
    "sqp_step",
    "stage_function",
    "stage_nodes",
    "trial_step",
    "trajectory_function",
]


@contextmanager
def stepwise_solves() -> Iterator[None]:
    """Inside the block every MPC solves step by step from Python (``MPC.compiled_solves``
    False): the reference path the compiled solve is checked against (the same plans)."""
    before = MPC.compiled_solves
    MPC.compiled_solves = False
    try:
        yield
    finally:
        MPC.compiled_solves = before
