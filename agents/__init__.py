"""Everything that decides: the Agent interface, its registry and the agents.

from agents import make_agent, agent_names
agent = make_agent("raceline")
"""

import racing_env.cache  # noqa: F401  first: the cache folder, before numba compiles anything
from racing_env import __version__

from . import alpha_agent, ibr, lookahead, mpc_agent, ppo_agent, ranked, simple  # noqa: F401  registers the built-in agents
from .base import (
    ENTRY_POINT_GROUP,
    Agent,
    agent_names,
    agent_parameters,
    import_agent_modules,
    make_agent,
    make_agent_spec,
    register_agent,
)
from .observations import adapt_observation, check_field_size

__all__ = [
    "__version__",
    "ENTRY_POINT_GROUP",
    "Agent",
    "adapt_observation",
    "agent_names",
    "agent_parameters",
    "check_field_size",
    "import_agent_modules",
    "make_agent",
    "make_agent_spec",
    "register_agent",
]
