"""``python -m lab experiments|evaluate`` (the same as ``slungpilot experiments|evaluate``)."""

import sys

from lab.cli import main

sys.exit(main())
