"""The model into a parallel loop: numba passes no named tuple into a
``prange`` loop (a :class:`Model`, its :class:`Chain`), but a plain tuple
of arrays it does. A parallel entry point flattens the model once
(:func:`flatten_model`) and each iteration rebuilds it
(:func:`model_from_flat`): the same arrays, nothing copied.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from drake_cfvol.kernel.types import Chain, Model

__all__ = ["flatten_model", "model_from_flat"]

# A constant to numba: the tuple's slices below are static.
_CHAIN_N = len(Chain._fields)


@njit(cache=True)
def flatten_model(m: Model) -> tuple[np.ndarray, ...]:
    """The model's arrays as one plain tuple: the chain's in :class:`Chain`'s
    order, then the rest in :class:`Model`'s."""
    return m.chain[:] + m[1:]


@njit(cache=True)
def model_from_flat(flat: tuple[np.ndarray, ...]) -> Model:
    """The :class:`Model` of :func:`flatten_model`'s tuple."""
    return Model(Chain(*flat[:_CHAIN_N]), *flat[_CHAIN_N:])
