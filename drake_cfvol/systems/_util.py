"""Shared helpers of the systems: vector arguments, and values and clips
that work for float and AutoDiffXd alike."""

import contextlib
import sys

import numpy as np

from drake_cfvol.exceptions import DimensionError, ParameterError


def _vector(value, k: int, name: str, *, positive: bool = False, nonnegative: bool = False) -> np.ndarray:
    v = np.broadcast_to(np.asarray(value, float), (k,)).copy() if np.ndim(value) == 0 else np.asarray(value, float)
    if v.shape != (k,):
        raise DimensionError(name, k, v.shape)
    if not np.all(np.isfinite(v)):
        raise ParameterError(f"{name} must be finite, got {v.tolist()}.")
    if positive and np.any(v <= 0):
        raise ParameterError(f"{name} must be > 0, got {v.tolist()}.")
    if nonnegative and np.any(v < 0):
        raise ParameterError(f"{name} must be >= 0, got {v.tolist()}.")
    return v


def _limits(value, k: int, name: str) -> np.ndarray:
    """Per-joint limits (k,) from a scalar or k values, each > 0 (inf: no limit)."""
    v = np.broadcast_to(np.asarray(value, float), (k,)).copy() if np.ndim(value) == 0 else np.asarray(value, float)
    v = v.reshape(-1) if v.ndim > 1 else v
    if v.shape != (k,):
        raise DimensionError(name, k, v.shape)
    if np.any(np.isnan(v)) or np.any(v <= 0):
        raise ParameterError(f"{name} must be > 0 (inf: no limit), got {v.tolist()}.")
    return v


def _values(x) -> np.ndarray:
    """Float values of a float or AutoDiffXd array (derivatives dropped)."""
    x = np.asarray(x)
    if x.dtype == object:
        # An AutoDiffXd, or a plain number where a clip put a constant bound.
        return np.array([float(e.value()) if hasattr(e, "value") else float(e) for e in x.ravel()]).reshape(x.shape)
    return x if x.dtype == np.float64 else x.astype(float)


def _clip(x, lo, hi):
    """Elementwise clip for float or AutoDiffXd arrays (the derivative is
    that of the active argument)."""
    x = np.asarray(x)
    if x.dtype != object:
        return np.minimum(np.maximum(x, lo), hi)  # np.clip's values, without its dispatch (several us a call)
    xv, lov, hiv = _values(x), _values(lo), _values(hi)
    lo, hi = np.asarray(lo, dtype=object), np.asarray(hi, dtype=object)
    return np.where(xv < lov, lo, np.where(xv > hiv, hi, x))


@contextlib.contextmanager
def _module_by_globals():
    """While open, pydrake's templates find the module that creates them
    from the creating frame's globals instead of ``inspect.stack()``, which
    reads the source of every frame on the stack (slow, and a templated
    system's instantiation makes two such look-ups). The same module;
    pydrake's own lookup where the globals name none."""
    try:
        from pydrake.common import cpp_template

        original = cpp_template._get_module_from_stack
    except (ImportError, AttributeError):  # a pydrake without it: nothing to speed up
        yield
        return

    def by_globals(frame=2):
        name = sys._getframe(frame).f_globals.get("__name__")
        module = sys.modules.get(name) if name is not None else None
        return module if module is not None else original(frame + 1)

    cpp_template._get_module_from_stack = by_globals
    try:
        yield
    finally:
        cpp_template._get_module_from_stack = original


def default_instantiation(template):
    """``template[None]`` (a ``TemplateSystem``'s float class), made without
    pydrake's stack inspection (:func:`_module_by_globals`)."""
    with _module_by_globals():
        return template[None]
