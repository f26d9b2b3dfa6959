"""``python -m pmabayes``: the command line.

Importing this module (as the documentation's build and ``pkgutil`` walks do) runs
nothing; only ``python -m pmabayes`` does.
"""

import sys

from pmabayes.cli import main

if __name__ == "__main__":
    sys.exit(main())
