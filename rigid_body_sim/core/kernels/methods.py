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
#: The sub-step weights (fractions of the step) of each splitting, padded to three for
#: the kernels: lie_poisson4's triple jump, and one Strang step for the others.
TRIPLE_JUMP = (YOSHIDA_W1, 1.0 - 2.0 * YOSHIDA_W1, YOSHIDA_W1)
ONE_STEP = (1.0, 0.0, 0.0)

#: rkmk4's Butcher tableau, the classical fourth-order Runge–Kutta method: stage
#: ``s`` starts at ``t + RK4_C[s] h`` from the state plus ``h Σ_j RK4_A[s][j] k_j``.
#: The kernels use its shape: each stage takes the slopes of the stage before only.
RK4_C = (0.0, 0.5, 0.5, 1.0)
RK4_A = ((0.0, 0.0, 0.0, 0.0),
         (0.5, 0.0, 0.0, 0.0),
         (0.0, 0.5, 0.0, 0.0),
         (0.0, 0.0, 1.0, 0.0))
#: Its weights, and those of the embedded third-order solution over the four stages
#: and the slopes at the new state (first same as last; Hairer, Nørsett & Wanner,
#: Solving ODEs I, II.4), as numerators over ``RK4_B_DENOMINATOR``, as the tableau is
#: written: ``(1, 2, 2, 1) / 6``. The kernels use their symmetry (``b0 = b3``,
#: ``b1 = b2``) and that the two solutions differ in the last two slopes only.
RK4_B_NUMERATORS = (1.0, 2.0, 2.0, 1.0)
RK4_B_HAT_NUMERATORS = (1.0, 2.0, 2.0, 0.0, 1.0)
RK4_B_DENOMINATOR = 6.0
