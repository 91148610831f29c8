"""The iterated-best-response agent ``ibr`` (:class:`IBRAgent`, the paper's Case IV baseline):
it reads its car's observation, hands every car's state to the solver
(:class:`agents.ibr_solver.IBR`, whose module describes the method) and applies the input
it returns.

The settings :class:`IBRConfig` (from :mod:`agents.ibr_data`) and the solver :class:`IBR` are
re-exported here, so ``from agents.ibr import IBR, IBRConfig`` keeps working.
"""

from __future__ import annotations

import numpy as np

from racing_env.track import Track
from racing_env.tracks import make_track
from racing_env.vehicle import VehicleParams
from racing_env.vehicles import FullSizeParams, vehicle_for_track

from .base import median_p99, register_agent
from .ibr_data import IBRConfig
from .ibr_kernels import _separation_pairs  # noqa: F401 (re-exported for the tests)
from .ibr_solver import IBR
from .mpc_agent import split_observation
from .threads import single_blas_thread

__all__ = ["IBR", "IBRAgent", "IBRConfig"]


@register_agent("ibr")
class IBRAgent:
    """Iterated-best-response agent (the paper's Case IV baseline, for any number of cars).

    Keywords: any :class:`IBRConfig` field (``rounds=6, horizon=20, tol=...``) or a full
    ``config``; ``vehicle`` (:class:`VehicleParams`, assumed for every car); ``n_preview``,
    the env's ``RaceConfig.n_preview`` (to read the observation layout). ``stats``: ``solves``
    (decisions), ``fallbacks`` (decisions whose QPs all failed, applying the shifted previous
    plan), ``restarts`` (plans restarted from a follower rollout), ``br_solves``,
    ``br_failures``, ``br_rejected`` (best-response QPs, failed ones, steps the merit check
    refused), ``rounds_mean``/``rounds_max`` (rounds until the plans stopped changing),
    ``unconverged`` (decisions still changing after ``rounds``), ``decision_ms_median``/``_p99``
    and ``br_ms_median``/``_p99`` (wall times). ``ibr.last`` holds the last decision's record.
    """

    spec_keywords_from = IBRConfig  # what ``**config_fields`` takes (agents.base.agent_parameters)

    def __init__(
        self,
        config: IBRConfig | None = None,
        vehicle: VehicleParams | FullSizeParams | None = None,
        n_preview: int = 10,
        **config_fields,
    ):
        if config is not None and config_fields:
            raise ValueError(
                f"give either config or IBRConfig fields, not both (got {sorted(config_fields)})"
            )
        known = set(IBRConfig.__dataclass_fields__)
        unknown = set(config_fields) - known
        if unknown:
            raise ValueError(
                f"unknown IBR parameter(s) {sorted(unknown)}; expected IBRConfig "
                f"fields: {', '.join(sorted(known))}"
            )
        if not (isinstance(n_preview, (int, np.integer)) and n_preview >= 0):
            raise ValueError(f"n_preview must be a non-negative integer, got {n_preview!r}")
        self.config = config or IBRConfig(**config_fields)
        self.vehicle_given = vehicle
        self.vehicle: VehicleParams | FullSizeParams = vehicle or VehicleParams()
        self.n_preview = n_preview
        self.ibr: IBR | None = None
        self.track: Track | None = None

    def reset(self, track: Track | str, agent_id: str = "car_0", seed: int | None = None) -> None:
        track = make_track(track)
        self.vehicle = vehicle_for_track(track, self.vehicle_given, "IBRAgent (ibr)")
        if self.ibr is None or self.track is not track:
            self.ibr = IBR(track, self.vehicle, self.config)
        self.track = track
        self.ibr.reset()
        self.agent_id = agent_id
        self._u_prev = np.zeros(2)

    @property
    def stats(self) -> dict:
        if self.ibr is None:
            return {}
        st = self.ibr.stats
        med, p99 = median_p99(st["decision_ms"])
        br_med, br_p99 = median_p99(st["br_ms"])
        rounds = np.asarray(st["rounds"], dtype=float)
        return {
            "solves": st["decisions"],
            "fallbacks": st["fallbacks"],
            "restarts": st["restarts"],
            "br_solves": st["br_solves"],
            "br_failures": st["br_failures"],
            "br_rejected": st["br_rejected"],
            "rounds_mean": float(rounds.mean()) if rounds.size else float("nan"),
            "rounds_max": int(rounds.max()) if rounds.size else 0,
            "unconverged": st["unconverged"],
            "decision_ms_median": med,
            "decision_ms_p99": p99,
            "br_ms_median": br_med,
            "br_ms_p99": br_p99,
        }

    def act(self, observation: np.ndarray) -> np.ndarray:
        if self.ibr is None:
            raise RuntimeError("IBRAgent.act() before reset(track, ...)")
        ego, others = split_observation(observation, self.n_preview)
        with single_blas_thread():  # results independent of the BLAS thread count
            u = self.ibr.solve(np.vstack([ego[None, :], others]), self._u_prev)
        self._u_prev = u
        return u.astype(np.float32)
