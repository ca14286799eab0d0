"""The plant: numba kernels for the two-body Hertzian impact.  No gymnasium, no configs, no files.

Public pieces: :func:`run.run_periods` and :func:`integrators.advance` (kernels),
:mod:`layout` (array layouts, frame and codes), :mod:`restitution` (damping calibration),
:mod:`energy` (energies), :mod:`hertz` (closed-form Hertz results).
"""
