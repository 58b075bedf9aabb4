"""slungpilot's companion application: model, planning, control, MAVLink and Zenoh I/O, CLI.

Numba caches compiled kernels per source file and does not notice when a kernel's callee in *another*
file changes (``sim_bridge.physics`` calls into ``sim_bridge.inner_loop``, ``companion.model`` and
``companion.wind``). So unless the user chose a cache folder, we key the cache folder by a hash of all
kernel sources: an edit anywhere in the chain compiles afresh instead of running a stale kernel.
"""

import hashlib
import os
from pathlib import Path

_KERNEL_SOURCES = (
    Path(__file__).with_name("model.py"),
    Path(__file__).with_name("wind.py"),
    Path(__file__).parent.parent / "sim_bridge" / "inner_loop.py",
    Path(__file__).parent.parent / "sim_bridge" / "physics.py",
)


def _kernel_cache_dir() -> str:
    h = hashlib.sha256()
    for p in _KERNEL_SOURCES:
        try:
            h.update(p.read_bytes())
        except OSError:
            h.update(p.name.encode())
    base = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "slungpilot" / "numba"
    return str(base / h.hexdigest()[:16])


if "NUMBA_CACHE_DIR" not in os.environ and "numba" not in __import__("sys").modules:
    os.environ["NUMBA_CACHE_DIR"] = _kernel_cache_dir()
