"""``python -m bayescal`` runs the command line (see :mod:`bayescal.cli.main`)."""

from .cli.main import console_main

console_main()
