"""Support for the controllers' single-sample fast path (batch_shape == ()): plain Python floats, no NumPy per op.

Why: one NumPy operation on a 3-vector costs far more call overhead than the arithmetic, and a control law is a few dozen of
them, while the live bridge runs ONE vehicle at up to 1 kHz. So a law is written once, per axis, with operations that
take a float or an array alike (``+ - * /``, ``abs`` and the functions below), and :func:`elementwise` runs it either
once on arrays (..., 3) (batched: the offline simulator) or once per axis on Python floats (one vehicle). SMC, STSM,
ATSM, ASTSM and the PID are written so: one law, no twin. Equality of the two shapes to ~1e-12 is tested in tests/controllers/test_single_sample_equivalence.py.

What is here:

* :func:`sgn`, :func:`clip`, :func:`root`, :func:`where` — ``np.sign``, ``np.clip``, ``np.sqrt``, ``np.where``, done
  without NumPy for one float (sgn(0) = 0, NaN stays NaN);
* :func:`elementwise` — runs a per-axis law on either shape; :func:`outputs` — its diagnostics and u;
* :func:`axis_floats` — a 3-vector (shape-(3,) array, tuple or list) as three Python numbers;
* :class:`AxisState` — a controller state attribute (e.g. ``alpha``) that is stored as a 3-tuple of
  floats on the single-sample path and always *reads* as an array, so users and tests see arrays;
* :class:`FloatDiagnostics` — the ``diagnostics()`` mapping of the fast path: 3-tuples stored, an
  array built only when a key is read.
"""

from __future__ import annotations

import math
from typing import Iterator, Mapping

import numpy as np


def sgn(x):
    """Sign like ``np.sign``: -1, +1, 0 for 0 (the paper's sgn(0) = 0), NaN for NaN; of one float without NumPy."""
    if type(x) is not float:
        return np.sign(x)
    return 1.0 if x > 0.0 else (-1.0 if x < 0.0 else x * 0.0)


def clip(x, lo, hi):
    """``np.clip`` (``lo <= hi``); NaN stays NaN; of one float without NumPy (arrays: ``np.minimum(np.maximum(..))``,
    the same values as ``np.clip`` at a fraction of its call cost)."""
    if type(x) is not float:
        return np.minimum(np.maximum(x, lo), hi)
    return lo if x < lo else (hi if x > hi else x)


def root(x):
    """Square root (``np.sqrt``); of one float by ``math.sqrt`` (both correctly rounded: the same value)."""
    return math.sqrt(x) if type(x) is float else np.sqrt(x)


def where(condition, a, b):
    """``np.where``; for one bool ``a if condition else b``."""
    if type(condition) is bool:
        return a if condition else b
    return np.where(condition, a, b)


def elementwise(law, single: bool, *args) -> tuple:
    """Run a per-axis ``law`` written once for both shapes: batched, once on arrays (..., 3) with (3,) constants
    broadcast; single sample (``single``), once per axis on the floats of every 3-tuple argument (other arguments, such
    as dt or a scalar gain, passed as they are). Returns the law's outputs: arrays, or 3-tuples of floats."""
    if not single:
        return law(*args)
    return tuple(zip(*[law(*axis) for axis in zip(*[a if type(a) is tuple else (a, a, a) for a in args])]))




def axis_floats(vec) -> tuple:
    """The three components of a single-sample 3-vector as Python numbers.

    Raises ValueError when ``vec`` is not one 3-vector (e.g. a batch of shape (n, 3) given to a
    controller built for batch_shape ()).
    """
    a, b, c = vec.tolist() if type(vec) is np.ndarray else vec
    if type(a) is list:
        raise ValueError(f"expected one 3-vector (batch_shape ()), got shape {np.shape(vec)}")
    return a, b, c


class AxisState:
    """Descriptor for a per-axis controller state (..., 3), e.g. ``alpha``, ``nu``, ``integrator``.

    Stored in ``obj._<name>``: a 3-tuple of floats when ``obj.batch_shape == ()`` (the fast path reads and
    writes the private attribute directly), else the array. Reading ``obj.<name>`` always gives an array
    (a fresh copy on the single-sample path: assign the whole attribute to change it). ``None`` (no
    previous sample yet) stays ``None``.
    """

    def __set_name__(self, owner, name: str) -> None:
        self.private = "_" + name

    def __get__(self, obj, objtype=None):
        if obj is None:
            return self
        value = getattr(obj, self.private)
        return value if value is None or type(value) is np.ndarray else np.array(value, dtype=float)

    def __set__(self, obj, value) -> None:
        if value is not None:
            if obj.batch_shape == ():
                value = tuple(np.asarray(value, dtype=float).reshape(3).tolist())
            else:
                value = np.asarray(value, dtype=float)
        setattr(obj, self.private, value)


class FloatDiagnostics(Mapping):
    """Read-only mapping name -> array (3,) built lazily from 3-tuples of floats (fast-path diagnostics)."""

    __slots__ = ("_values",)

    def __init__(self, values: dict) -> None:
        self._values = values

    def __getitem__(self, key: str) -> np.ndarray:
        return np.array(self._values[key], dtype=float)

    def __iter__(self) -> Iterator[str]:
        return iter(self._values)

    def __len__(self) -> int:
        return len(self._values)

    def __contains__(self, key) -> bool:
        return key in self._values

    def floats(self, key: str) -> tuple:
        """The stored 3-tuple for ``key`` (no array)."""
        return self._values[key]


def outputs(single: bool, diag: dict) -> tuple:
    """(diagnostics mapping, u) of one update from its diagnostics (key ``"u"`` included): a FloatDiagnostics and u as
    an array (3,) for a single sample, else the dict and its arrays as they are."""
    return (FloatDiagnostics(diag), np.array(diag["u"])) if single else (diag, diag["u"])


def diagnostics_floats(diag: Mapping, key: str):
    """3-tuple of floats for ``key`` from any controller's diagnostics, or None when absent."""
    if isinstance(diag, FloatDiagnostics):
        return diag.floats(key) if key in diag else None
    value = diag.get(key)
    return None if value is None else tuple(np.asarray(value, dtype=float).reshape(-1)[:3].tolist())
