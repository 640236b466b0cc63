"""``python -m pan1_env``: the same command line as the ``pan1-env`` console script."""

import sys

from .cli import main

sys.exit(main())
