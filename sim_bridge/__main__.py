"""``python -m sim_bridge``: start the bundled SITL vehicle (see ``--help`` and docs/sitl.md)."""

import sys

from sim_bridge.cli import main

sys.exit(main())
