"""``python -m sim`` from a source checkout (the installed package runs as ``mavastsm sim``)."""

import sys

from .command import main

sys.exit(main())
