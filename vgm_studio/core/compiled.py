"""Kernels compiled with numba, for the loops numpy cannot express without a pass per step."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, TypeVar, cast

import numba

_F = TypeVar("_F", bound=Callable[..., Any])


def kernel(f: _F) -> _F:
    """Compiles ``f`` on its first call, kept in ``__pycache__`` for the next process; the
    compiled code lets go of the GIL, so threads run it at once. Division follows numpy (a
    float divided by zero is inf or NaN, not an exception), as the numpy it replaces did."""
    return cast(_F, numba.njit(cache=True, nogil=True, error_model="numpy")(f))
