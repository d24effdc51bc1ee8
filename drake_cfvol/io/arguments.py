"""The public API's arguments checked where they enter: numbers, arrays of numbers, file paths and types, each
refused with a :class:`~drake_cfvol.exceptions.CfvolError` that names the argument (a ``TypeError`` from deep
inside names nothing the caller wrote)."""

from __future__ import annotations

import numbers
import os
from pathlib import Path

import numpy as np

from drake_cfvol.exceptions import DimensionError, ParameterError

__all__ = ["file_path", "got", "instance", "names", "real_array", "real_number", "text", "whole_number"]


def got(value) -> str:
    """What a caller passed, for a message: its type and a short repr."""
    text = repr(value)
    return f"{type(value).__name__} {text if len(text) <= 60 else text[:57] + '...'}"


def real_number(value, name: str) -> float:
    """``value`` as a float: a real number (a bool, a string or an array is refused).

    Raises:
        ParameterError: it is not a real number.
    """
    if isinstance(value, np.ndarray) and value.shape == ():
        value = value[()]
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise ParameterError(f"{name} must be a number, got {got(value)}.")
    return float(value)


def whole_number(value, name: str, *, minimum: int = 0) -> int:
    """``value`` as an int: a whole number >= ``minimum`` (a float, even 10.0, is refused: it says a count).

    Raises:
        ParameterError: it is not a whole number, or below ``minimum``.
    """
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise ParameterError(f"{name} must be a whole number >= {minimum}, got {got(value)}.")
    if value < minimum:
        raise ParameterError(f"{name} must be >= {minimum}, got {value}.")
    return int(value)


def real_array(value, name: str, *, ndim: int | tuple[int, ...] | None = None) -> np.ndarray:
    """``value`` as a float array: numbers, a list of numbers or an array (a dict, a string or None is refused,
    as numpy would read them as one object), of ``ndim`` dimensions if given.

    Raises:
        ParameterError: it does not hold numbers.
        DimensionError: it has another number of dimensions.
    """
    if value is None or isinstance(value, (dict, str, bytes, set)):
        raise ParameterError(f"{name} must be an array of numbers, got {got(value)}.")
    try:
        # Strings are refused even where numpy would read them ("0" as 0.0): they were meant as something else.
        if np.asarray(value).dtype.kind not in "biuf":
            raise ValueError("it holds something other than numbers")
        a = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as e:
        raise ParameterError(f"{name} must be an array of numbers, got {got(value)} ({e}).") from None
    wanted = (ndim,) if isinstance(ndim, int) else ndim
    if wanted is not None and a.ndim not in wanted:
        raise DimensionError(name, " or ".join(f"{n} dimension(s)" for n in wanted), f"shape {a.shape}")
    return a


def names(value, name: str) -> list[str]:
    """``value`` as a list of names: a list or tuple of strings (a single string is refused: its letters
    are not names).

    Raises:
        ParameterError: it is not.
    """
    if isinstance(value, np.ndarray):
        value = value.tolist()
    if not isinstance(value, (list, tuple)) or not all(isinstance(v, str) for v in value):
        raise ParameterError(f"{name} must be a list of names (str), got {got(value)}.")
    return list(value)


def text(value, name: str) -> str:
    """``value`` itself if it is a str.

    Raises:
        ParameterError: it is not.
    """
    if not isinstance(value, str):
        raise ParameterError(f"{name} must be a str, got {got(value)}.")
    return value


def file_path(value, name: str) -> Path:
    """``value`` as a Path: a string or a path-like object.

    Raises:
        ParameterError: it is neither.
    """
    if not isinstance(value, (str, os.PathLike)) or (isinstance(value, str) and not value):
        raise ParameterError(f"{name} must be a file's path (a str or pathlib.Path), got {got(value)}.")
    return Path(value)


def instance(value, cls: type, name: str, how: str = ""):
    """``value`` itself if it is a ``cls``.

    Raises:
        ParameterError: it is not, naming ``name``, what it is, and ``how`` to get a ``cls``.
    """
    if not isinstance(value, cls):
        hint = f" ({how})" if how else ""
        raise ParameterError(f"{name} must be a {cls.__name__}{hint}, got {got(value)}.")
    return value
