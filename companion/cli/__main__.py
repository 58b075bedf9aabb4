"""``python -m companion.cli``: the same as ``slungpilot``."""

import sys

from companion.cli.main import main

sys.exit(main())
