"""alpha-racer's racing world: tracks, racing line, vehicle model, PettingZoo and Gymnasium envs.

Quick use::

    import racing_env
    env = racing_env.parallel_env(n_cars=3)          # PettingZoo ParallelEnv
    aec = racing_env.env(n_cars=3)                   # PettingZoo AEC env
    import gymnasium; gymnasium.make("alpha_racer/HeadToHead-v2")   # single learner
"""

from . import cache as _cache  # noqa: F401  first: the cache folder, before numba compiles anything
from .config import RaceConfig, RulesConfig, StartConfig
from .core import BatchedRaces
from .parallel_env import RacingParallelEnv, env, parallel_env, raw_env
from .track import Track
from .tracks import load_tumftm_csv, make_track, random_track, track_names
from .vehicle import VehicleParams

__all__ = [
    "BatchedRaces",
    "RaceConfig",
    "RacingParallelEnv",
    "RulesConfig",
    "StartConfig",
    "Track",
    "VehicleParams",
    "env",
    "load_tumftm_csv",
    "make_track",
    "parallel_env",
    "random_track",
    "raw_env",
    "track_names",
]

from . import registration as _registration  # noqa: E402, F401

__version__ = "0.1.0"
