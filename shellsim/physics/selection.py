"""Vertex selections by a coordinate threshold: one grammar for ``simulate --pin`` and ``wind --anchor``.

A rule is ``AXIS OP VALUE[%]``: ``AXIS`` is x, y or z; ``OP`` is ``<``, ``<=``, ``>`` or ``>=``; ``VALUE`` is
a number in world units, or with ``%`` a percentage of the vertices' extent along the axis measured from
its minimum (``z<5%``: the lowest 5 %). Parsed by a strict regular expression, never evaluated.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

import numpy as np

from neural.errors import InputError

_NUMBER = r"[+-]?(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][+-]?\d+)?"
_RULE = re.compile(rf"\s*([xyzXYZ])\s*(<=|>=|<|>)\s*({_NUMBER})\s*(%?)\s*")
GRAMMAR = (
    "expected AXIS OP VALUE, e.g. 'z<0.1', 'x>=-2' or 'z<5%' (AXIS x, y or z; OP <, <=, > or >=; "
    "VALUE a number in world units or a percentage of the extent along AXIS)"
)
_COMPARE = {"<": np.less, "<=": np.less_equal, ">": np.greater, ">=": np.greater_equal}


@dataclass(frozen=True)
class Selection:
    """``AXIS OP VALUE[%]``: the vertices whose coordinate ``axis`` (0, 1, 2) compares with ``value`` (world
    units, or percent of the vertices' extent along the axis, measured from its minimum); ``text`` is the
    rule as given, for messages."""

    axis: int
    op: str
    value: float
    percent: bool
    text: str

    @property
    def sign(self) -> float:
        """+1 for ``<``/``<=`` (the selection lies below the threshold), -1 for ``>``/``>=``."""
        return 1.0 if self.op in ("<", "<=") else -1.0

    def threshold(self, vertices: np.ndarray) -> float:
        """The rule's threshold in world units for ``vertices`` (V, 3)."""
        if not self.percent:
            return self.value
        coord = vertices[:, self.axis]
        return float(coord.min() + self.value / 100.0 * (coord.max() - coord.min()))

    def select(self, vertices: np.ndarray) -> np.ndarray:
        """(V,) bool mask of the vertices (V, 3) the rule selects."""
        return _COMPARE[self.op](vertices[:, self.axis], self.threshold(vertices))

    def refusal(self, name: str, vertices: np.ndarray, what: str = "no") -> InputError:
        """The error (a :class:`~shellsim.errors.SettingError` of the setting ``name``) for a rule that
        selects ``what`` ("no", "every") of the cage vertices (V, 3), with where they lie along its axis."""
        from shellsim.errors import SettingError

        coord = vertices[:, self.axis]
        return SettingError(
            name,
            f"{self.text!r} selects {what} cage vertex ({'xyz'[self.axis]} spans "
            f"{coord.min():.4g} .. {coord.max():.4g})",
        )


def parse_selection(text, name: str | None = None) -> Selection:
    """Parse ``"z<0.1"``, ``"x >= -2"``, ``"y>95%"``; anything else is an :class:`InputError` quoting it,
    after ``name`` (what the rule is given as: ``"anchor"``, ``"--pin"``) when given."""
    match = _RULE.fullmatch(text) if isinstance(text, str) else None
    value = float(match.group(3)) if match else math.nan
    if not math.isfinite(value):
        raise InputError(f"{name + ' ' if name else ''}{text!r}: {GRAMMAR}")
    axis = "xyz".index(match.group(1).lower())
    return Selection(axis, match.group(2), value, bool(match.group(4)), text)


def select_vertices(rules: list[Selection], vertices: np.ndarray, name: str) -> np.ndarray:
    """(V,) bool: the vertices (V, 3) that any of ``rules`` selects; a rule that selects none is an
    :class:`InputError` naming it as ``name``."""
    chosen = np.zeros(len(vertices), bool)
    for rule in rules:
        mask = rule.select(vertices)
        if not mask.any():
            raise rule.refusal(name, vertices)
        chosen |= mask
    return chosen


def selection_text(text: str) -> str:
    """``text`` if it is a selection :func:`parse_selection` accepts, else a ``ValueError`` saying what is
    expected (the ``parse`` of a settings option, :mod:`shellsim.settings`)."""
    try:
        parse_selection(text)
    except InputError:
        raise ValueError(GRAMMAR) from None
    return text
