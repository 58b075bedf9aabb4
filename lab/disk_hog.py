"""A process that keeps the disk busy the way a ``git clone`` or an install does: a tree of thousands of files copied,
synced and removed, round after round.

``python -m lab.disk_hog --dir DIR [--source TREE]``: each round copies TREE (default: this Python's
site-packages, ~17,000 files and 1.5 GB in the project's venv) into DIR, calls ``sync``, then removes the copy;
rounds go on until SIGINT/SIGTERM, then it prints ``{"written_mb": ..., "files": ..., "rounds": ...}``. Used by
the ``disk_storm`` fault scenario (``lab.faults``). On the development VM large sequential writes (64 MB files,
fsync-ed) and a synthetic tree of small files did not stall the companion; a ``git clone`` of a 400 MB
repository during the Zenoh flood did.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import shutil
import signal
import sys
import sysconfig
from pathlib import Path


class _Stop(Exception):
    pass


def main(argv: list[str]) -> int:
    p = argparse.ArgumentParser(prog="python -m lab.disk_hog", description=__doc__.splitlines()[0])
    p.add_argument("--dir", type=Path, required=True)
    p.add_argument("--source", type=Path, default=Path(sysconfig.get_paths()["purelib"]))
    a = p.parse_args(argv)
    stop: list[int] = []
    signal.signal(signal.SIGINT, lambda *_: stop.append(1))
    signal.signal(signal.SIGTERM, lambda *_: stop.append(1))
    written = files = rounds = 0

    def copy(src: str, dst: str) -> None:
        nonlocal written, files
        if stop:
            raise _Stop
        shutil.copyfile(src, dst)
        written += os.path.getsize(dst)
        files += 1

    print("hogging", file=sys.stderr, flush=True)
    try:
        while not stop:
            dst = a.dir / f"round-{rounds}"
            with contextlib.suppress(_Stop, shutil.Error):
                shutil.copytree(a.source, dst, copy_function=copy, symlinks=True)
            os.sync()  # as ``git clone && sync``
            shutil.rmtree(dst, ignore_errors=True)
            rounds += 1
    finally:
        shutil.rmtree(a.dir, ignore_errors=True)
    print(json.dumps({"written_mb": round(written / 2**20, 1), "files": files, "rounds": rounds}), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
