"""``python -m fgloc`` runs the command line."""

import sys

from fgloc.cli import main

sys.exit(main())
