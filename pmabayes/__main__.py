"""``python -m pmabayes``: the command line."""

import sys

from pmabayes.cli import main

sys.exit(main())
