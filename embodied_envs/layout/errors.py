"""Exception types of the layout package."""

from __future__ import annotations


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
        msg += (
            f'cannot place "{node}": no pose out of {attempts} candidates satisfied the '
            f'constraints; the one failed most often was "{constraint}"'
        )
        if detail:
            msg += f" ({detail})"
        msg += ". Fix: use a larger parent surface, fewer or smaller objects, or relax the limit."
        super().__init__(msg)

    def with_source(self, source: str) -> PlacementError:
        """The same error, naming the layout file it concerns."""
        return PlacementError(self.node, self.constraint, self.attempts, self.detail, source)
