"""The one exception type of the core: bad input, naming the field at fault."""

from __future__ import annotations


class SpecError(ValueError):
    """
    Invalid input; ``field`` is the dotted key path of the offending value.

    The message reads ``"<field>: <problem>"``. Callers that know more context
    (a scene file, a list index) re-raise with :meth:`within`.
    """

    def __init__(self, field: str, problem: str) -> None:
        self.field = field
        self.problem = problem
        super().__init__(f'{field}: {problem}' if field else problem)

    def within(self, prefix: str) -> 'SpecError':
        """Return the same error with ``prefix`` prepended to its field path."""
        if not prefix:
            return SpecError(self.field, self.problem)
        joined = f'{prefix}.{self.field}' if self.field and not self.field.startswith('[') \
            else f'{prefix}{self.field}'
        return SpecError(joined, self.problem)


class InconsistentConstraintError(SpecError):
    """A constraint that no configuration satisfies together with the others (refused)."""


class DivergenceError(RuntimeError):
    """
    A step produced a non-finite state; the simulation stays at the last finite one.

    Not bad input but a step the method could not take (a step size far too
    large for the motion, a stiff wrench). ``time`` is the simulation time (s)
    the state stays at and ``bodies`` the names of the bodies that diverged.
    """

    def __init__(self, time: float, bodies: list) -> None:
        self.time = time
        self.bodies = bodies
        super().__init__(f'the step from t = {time:.9g} s gave a non-finite state (bodies '
                         f'{bodies}); the simulation stays at t = {time:.9g} s '
                         f'(a smaller dt resolves the motion)')
