"""Exception types of the layout package, and the check that refuses a number out of range."""

from __future__ import annotations

import math
import numbers


class LayoutError(ValueError):
    """A layout file or one of its asset folders is invalid.

    The message names the file, the node and the field, and says how to fix it. When several
    problems are found at once, ``problems`` lists each of them and the message joins them.
    """

    def __init__(self, problems: str | list[str]):
        self.problems = [problems] if isinstance(problems, str) else list(problems)
        if len(self.problems) == 1:
            message = self.problems[0]
        else:
            message = f"{len(self.problems)} problems:\n" + "\n".join(
                f"  - {p}" for p in self.problems
            )
        super().__init__(message)


class PlacementError(RuntimeError):
    """An object could not be placed within the attempt budget.

    Attributes:
        node: the object that could not be placed.
        constraint: the constraint that rejected the most candidates.
    """

    def __init__(
        self, node: str, constraint: str, attempts: int, detail: str = "", source: str = ""
    ):
        self.node = node
        self.constraint = constraint
        self.attempts = attempts
        self.detail = detail
        self.source = source
        msg = f"{source}: " if source else ""
        if attempts:
            msg += (
                f'cannot place "{node}": no pose out of {attempts} candidates satisfied the '
                f'constraints; the one failed most often was "{constraint}"'
            )
        else:  # a constraint no candidate can meet: none was drawn
            msg += f'cannot place "{node}": no candidate can meet "{constraint}"'
        if detail:
            msg += f" ({detail})"
        msg += ". Fix: use a larger parent surface, fewer or smaller objects, or relax the limit."
        super().__init__(msg)

    def with_source(self, source: str) -> PlacementError:
        """The same error, naming the layout file it concerns."""
        return PlacementError(self.node, self.constraint, self.attempts, self.detail, source)


def check_number(
    where: str,
    value,
    lo: float,
    hi: float,
    *,
    integer: bool = False,
    lo_open: bool = False,
    hi_open: bool = False,
) -> None:
    """Refuse a value that is not a (finite) number in its range, naming it and the range.

    Raises:
        ValueError: ``where=value`` is not a number, not an integer when ``integer``, or
            outside ``[lo, hi]`` (``(`` / ``)`` when open).
    """
    kind = "an integer" if integer else "a number"
    ok_type = isinstance(value, numbers.Integral if integer else numbers.Real) and not isinstance(
        value, bool
    )
    span = f"{'(' if lo_open else '['}{lo}, {hi}{')' if hi_open else ']'}"
    if not ok_type:
        raise ValueError(f"{where}={value!r} must be {kind} in {span}")
    v = float(value)
    if not (
        math.isfinite(v) and (v > lo if lo_open else v >= lo) and (v < hi if hi_open else v <= hi)
    ):
        raise ValueError(f"{where}={value!r} is outside {span}. Fix: give {kind} in {span}")
