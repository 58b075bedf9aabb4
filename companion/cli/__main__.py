"""``python -m companion.cli``: the same as ``slungpilot``."""

from companion.cli.main import run

run()
