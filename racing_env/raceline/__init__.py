"""The paper's single-agent racing line (appendix B): minimum-curvature path + speed library.

``RacelineConfig(objective="lap_time")`` goes beyond the paper: the same path problem with a
shortest-path term added, its weight searched per track for the shortest lap estimate
(:func:`lap_time_weight_search`).

Two stages, both on a closed :class:`~racing_env.track.Track`:

1. **Minimum-curvature path.** Lateral offsets ``n_k`` [m] (left positive) along the centre-line
   normals at ``N`` uniformly spaced centre-line stations (about one per
   ``RacelineConfig.point_spacing`` m, never more than the track grid has) minimise the
   curvature per metre of path, ``sum_k kappa_k(n)^2 |r_k'| h`` (``|r_k'|`` the path length per
   unit of centre-line ``s``, ``h`` the station spacing; counted per station instead, a line
   running wide would get its longer path for free) subject to
   ``-w_right_k + w_veh/2 + margin <= n_k <= w_left_k - w_veh/2 - margin``.
   The curvature ``kappa = (x' y'' - y' x'') / (x'^2 + y'^2)^(3/2)`` of the path
   ``r_k = c_k + n_k N_k`` is linearised in ``n``: the first derivatives ``x', y'`` and the
   denominator (and the path weight ``|r_k'|``) are frozen at the current iterate, the second derivatives are linear in ``n``
   through periodic finite-difference matrices. Each linearisation is a box-constrained
   least-squares problem (a convex QP) solved by a primal-dual active-set method (sparse
   direct solves; OSQP and DAQP through CasADi as fallbacks).
   (``RacelineConfig.linearization="exact"`` uses the full Jacobian instead, see there.) The
   line is re-linearised until the QP solution moves the offsets by less than
   ``RacelineConfig.tol`` [m] (at most ``max_iter`` times, otherwise a
   :class:`RacelineConvergenceWarning`; the exact scheme also stops once the true cost no
   longer decreases by more than 1e-6 relative); where the frozen iteration stops contracting (it can cycle at
   a tight hairpin) the update is under-relaxed. The offsets are then
   interpolated back (periodic cubic spline, clipped to the bounds) to every track grid point.

2. **Speed profile** ``vx(s)`` along the line for the car's g-g-v envelope scaled by ``mu``
   (:mod:`racing_env.envelope`; ``mu = 1`` is the car's own limit: the steering bound, the
   Pacejka tyres and the speed-dependent motor force), by forward (drive) and backward
   (braking) passes repeated around the closed lap until nothing changes:

   * ``vx <=`` the envelope's quasi-steady corner speed of ``kappa`` (:func:`speed_limit`)
     and ``vx <= vehicle.top_speed``;
   * drive ``<= mu ax_max(v, v^2 |kappa|)``, negative in fast corners where the motor cannot
     hold the speed, and braking ``<= -mu ax_min(v, v^2 |kappa|)`` (:func:`accel_limits`).

   The discrete scheme, with ``ds_k = s_{k+1} - s_k`` along the racing line, is exactly
   ``v_{k+1}^2 - v_k^2 <= 2 ds_k a_acc(v_k, kappa_k)`` and
   ``v_k^2 - v_{k+1}^2 <= 2 ds_k a_brk(v_{k+1}, kappa_{k+1})`` (see :func:`accel_limits`).
   A *library* of profiles over ``mu`` in ``[mu_min, mu_max]`` is stored and linearly
   interpolated in ``mu`` (:meth:`Raceline.speed_at`).

Units: SI throughout (m, s, rad, m/s, m/s^2). ``s_track`` is arc length along the *centre line*
(the coordinate the simulator and the controllers use), ``s`` arc length along the racing line.

Use :func:`get_raceline` (cached on disk and in memory); :func:`compute_raceline` always computes.

Modules, one job each: :mod:`.config` (the settings and the cache key), :mod:`.path` (the
line's geometry), :mod:`.boxqp` (the QP of each linearisation), :mod:`.optimise` (the
minimum-curvature and lap-time lines, :func:`compute_raceline`), :mod:`.speed` (the speed
profile), :mod:`.result` (:class:`Raceline`, its files and plot), :mod:`.cache` (the disk cache).
"""  # noqa: E501

from .boxqp import box_qp_active_set, box_qp_interior_point
from .cache import cache_dir, cache_path, clear_memo, get_raceline
from .config import (
    CACHE_VERSION,
    LENGTH_WEIGHTS,
    OBJECTIVES,
    SOURCES,
    TOL_PER_WIDTH,
    RacelineConfig,
    RacelineConvergenceWarning,
    cache_key,
)
from .optimise import compute_raceline, lap_time_weight_search, minimum_curvature_offsets
from .path import offset_bounds
from .result import CSV_COLUMNS, Raceline, plot_raceline
from .speed import G, accel_limits, lap_time_of, speed_limit, speed_profile

__all__ = [
    "CACHE_VERSION",
    "CSV_COLUMNS",
    "G",
    "LENGTH_WEIGHTS",
    "OBJECTIVES",
    "SOURCES",
    "TOL_PER_WIDTH",
    "Raceline",
    "RacelineConfig",
    "RacelineConvergenceWarning",
    "accel_limits",
    "box_qp_active_set",
    "box_qp_interior_point",
    "cache_dir",
    "cache_key",
    "cache_path",
    "clear_memo",
    "compute_raceline",
    "get_raceline",
    "lap_time_of",
    "lap_time_weight_search",
    "minimum_curvature_offsets",
    "offset_bounds",
    "plot_raceline",
    "speed_limit",
    "speed_profile",
]
