"""Pipelines and the ``alpha-racer`` command line: collect, train, self-play, benchmark, analyses."""

from racing_env import __version__  # noqa: F401  (imports racing_env.cache first: the cache folder)
