"""Suite-wide settings: the hypothesis profile.

The README's test command and CI load the ``ci`` profile: derandomised (each test draws the
same examples on every run, from a seed derived from the test) and without the example
database, so a run passes or fails the same way every time. Contributors who want fresh
draws run ``HYPOTHESIS_PROFILE=explore python -m pytest -q -n 2``; a falsifying example it
finds belongs in the test as an explicit ``@example`` before the fix lands.
"""

import os

from hypothesis import settings

settings.register_profile("ci", derandomize=True, database=None, print_blob=True)
settings.register_profile("explore", derandomize=False, print_blob=True)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))
