"""The compiled core (numba): SO(3) maths, chain kinematics and the GJM, the one-sided Jacobi
SVD, the inverse filters, the planner's step loop with running metrics, and the replay's
integrator. Every function here works on plain float64 arrays (SI units, rad) and imports
nothing from the rest of the engine; the modules above it are thin Python wrappers.

All kernels are compiled with ``cache=True`` (numba's on-disk cache, ``NUMBA_CACHE_DIR`` or the
``__pycache__`` folders beside these files), ``nogil=True`` (threads run them in parallel) and
``error_model="numpy"`` (a division by zero gives inf or nan, which the plan reports, instead of
raising inside compiled code).
"""
