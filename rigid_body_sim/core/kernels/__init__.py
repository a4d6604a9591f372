"""
The compiled kernels (numba): plain functions over flat float64 and int64 arrays.

They import only one another, numba, numpy and math; never the classes of
:mod:`rigid_body_sim.core` that call them (a test checks). One module per concern:

``views``
    Views of arrays without reference counting, tables of array addresses.
``so3``
    Unit quaternions and rotation matrices, one body at a time.
``methods``
    The integration methods' codes and coefficients (the one copy).
``free_step``
    A whole step of bodies no constraint couples; outputs, state distances.
``rows``
    The constraint rows' geometry and rates (point, dot, line, distance, angle).
``tree_solve``, ``loop_solve``
    The constraint system of a forest in tree order, and of a spanning forest
    plus the Schur complement of the rows that close loops.
``nullspace_solve``
    A prototype (issue 19, not yet a path of the step): a forest's system in
    articulated-inertia form, each joint's freedoms eliminated instead of its rows.
``constrained_step``
    A whole step of one component of the constraint graph (RATTLE and SHAKE).
``complementarity``
    Projected Gauss–Seidel sweeps of a box-constrained LCP (the rows with bounds,
    :mod:`..complementarity`).
``joints``
    Joint coordinates and rates from the bodies' outputs, and the limits' watch.
``contact``
    Collision detection: the broad phase (a hashed grid) and the narrow phases of the
    primitive shapes, with their manifolds (:mod:`..shapes`).
``convex``
    GJK, EPA and the features of convex shapes: the pairs without a closed form (a
    cylinder on a box or on a cylinder).
``contact_step``
    A whole step of free bodies with contact: the rows, the Delassus operator by its
    3 × 3 blocks, the contact LCP island by island, impacts located, depths projected.
``sparse_box``
    The box QP of a block-sparse operator by MPRGP (issue 21, not yet a path of the
    step): the inner solve for islands too large to factor densely.

:mod:`..kernel_cache` treats every module of this package as one unit.
"""
