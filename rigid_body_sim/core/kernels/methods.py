"""
The integration methods' codes and coefficients: the one copy.

Both the integrator classes of :mod:`..integrators` and the compiled steps read
these; the methods themselves are documented in :mod:`..integrators`.
"""

SYMPLECTIC_EULER, LIE_POISSON2, LIE_POISSON4, RKMK4 = 0, 1, 2, 3

#: Yoshida's triple jump (Phys. Lett. A 150, 262, 1990): lie_poisson4 composes
#: lie_poisson2 steps of ``(W1, 1 - 2 W1, W1)`` times the step.
_W1 = 1.0 / (2.0 - 2.0 ** (1.0 / 3.0))
