"""``python -m bayescal`` runs the command line (see :mod:`bayescal.cli.main`)."""

import sys

from .cli.main import main

sys.exit(main())
