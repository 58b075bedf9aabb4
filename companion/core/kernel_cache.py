"""Where numba keeps the compiled kernels: a folder keyed by the hash of the kernel sources.

Numba caches compiled kernels per source file and does not notice when a kernel's callee in *another*
file changes (``sim_bridge.physics`` calls into ``sim_bridge.inner_loop``, ``companion.core.model`` and
``companion.core.wind``). So every module that defines cached kernels calls :func:`use_kernel_cache` with
the sources its kernels depend on, just before it defines them: an edit anywhere in the chain compiles
afresh instead of running a stale kernel. Numba reads ``numba.config.CACHE_DIR`` when a ``cache=True``
kernel is decorated, so each module's kernels land in the folder of their own dependency set.
A user's ``NUMBA_CACHE_DIR`` always wins.
"""

from __future__ import annotations

import hashlib
import os
import sys
from pathlib import Path

import numba

#: The companion's own kernel sources (``companion.core``): every kernel elsewhere calls into these.
CORE_KERNEL_SOURCES = (Path(__file__).with_name("model.py"), Path(__file__).with_name("wind.py"))


def kernel_cache_dir(sources: tuple[Path, ...]) -> Path:
    """The cache folder for kernels that depend on ``sources``: ``~/.cache/slungpilot/numba/<hash>``."""
    h = hashlib.sha256()
    for p in sources:
        try:
            h.update(p.read_bytes())
        except OSError:  # e.g. running from a zip: fall back to the file name
            h.update(p.name.encode())
    base = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "slungpilot" / "numba"
    return base / h.hexdigest()[:16]


def use_kernel_cache(*extra_sources: Path) -> None:
    """Send the kernels decorated next to the folder keyed by the core sources plus ``extra_sources``."""
    if os.environ.get("NUMBA_CACHE_DIR"):
        return
    numba.config.CACHE_DIR = str(kernel_cache_dir(CORE_KERNEL_SOURCES + tuple(extra_sources)))


def skip_numba_blas_probe() -> None:
    """Numba's first kernel load imports ``numba.np.arraymath``, which imports ``scipy.linalg`` only to see whether
    BLAS exists for ``np.dot`` & co. inside compiled code (~0.16 s, and the only reason the vehicle or ``fly`` would
    import scipy). No kernel of ours uses BLAS inside compiled code, so a process that runs only our kernels (the
    vehicle, ``slungpilot fly``) answers the probe "no BLAS" without importing scipy; call this before the first
    kernel loads, and only in a program of our own (a user's kernel with ``np.dot`` would then fail to compile with
    numba's "scipy 0.16+ is required" error). Does nothing once numba has probed."""
    if "numba.np.arraymath" not in sys.modules:
        sys.modules.setdefault("scipy.linalg.cython_blas", None)  # type: ignore[assignment]
