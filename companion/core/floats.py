"""Tiny vectors as Python floats, for the control tick's element-by-element arithmetic (a numpy scalar costs
~10x a float there; ``tolist()`` gives bitwise the same values)."""

from __future__ import annotations

import numpy as np


def floats(v):
    """``v`` as a list of floats when it is an ndarray, else ``v`` itself (a list or tuple the caller reads)."""
    return v.tolist() if isinstance(v, np.ndarray) else v
