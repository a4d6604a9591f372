"""
The integration methods' codes and coefficients: the one copy.

Both the integrator classes of :mod:`..integrators` and the compiled steps read
these; the methods themselves are documented in :mod:`..integrators`.
"""

from enum import IntEnum


class Method(IntEnum):
    """The code of each integration method, as the compiled steps take it."""

    SYMPLECTIC_EULER = 0
    LIE_POISSON2 = 1
    LIE_POISSON4 = 2
    RKMK4 = 3


#: Yoshida's triple jump (Phys. Lett. A 150, 262, 1990): lie_poisson4 composes
#: lie_poisson2 steps of ``(w1, 1 - 2 w1, w1)`` times the step.
YOSHIDA_W1 = 1.0 / (2.0 - 2.0 ** (1.0 / 3.0))
