"""``python -m experiments.cli``: the ``alpha-racer`` command line."""

import sys

from experiments.cli import main

sys.exit(main())
