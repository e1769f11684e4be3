"""``python -m bayescal`` runs the command line (see :mod:`bayescal.cli`)."""

import sys

from .cli import main

sys.exit(main())
