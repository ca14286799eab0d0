"""Model-predictive control of the impact: the prediction model (:mod:`.model`) and the
real-time-iteration iLQR solver (:mod:`.solver`) shared by the MPC laws
(``mpc-state`` on the true state, :mod:`impact_env.control.laws.mpc_state`), and its C text
(:mod:`.c_text`).

Interface for a law built on the solver (stable):

* constants: :class:`impact_env.control.mpc.model.Constants` (float64 vector, SI), built from a
  scene by :func:`impact_env.control.laws.mpc_state.solver_constants`; a law with more constants
  puts these first (its own follow, ``positions(TheirConstants, start=model.N_CONSTANTS)``)
  and passes ``k`` whole (the solver reads only its own entries).
* memory: ``mem[:solver.MEMORY]`` (zero at the episode start); a law with more memory puts its
  own after ``solver.MEMORY`` and passes the slice ``mem[:solver.MEMORY]`` (or the whole row).
* ``solver.mpc_tick(x1, v1, x2, v2, k, mem) -> f``: a numba kernel, the state estimate in SI
  (x1 m, v1 m/s, x2 m, v2 m/s, x down-positive as the plant has it), returns the force demand
  f (N, upwards on body 2), inside ``|f| <= umax`` and the slew box.  The shaker's augmented
  state lives in ``mem[solver.STATE + 4:solver.STATE + 7]`` (the model driven by the returned
  demands); a caller with its own estimate of it may write it there before the call.
* ``solver.solve(k, mem) -> f``: the core on the augmented state ``mem[STATE:STATE + 7]``,
  without the shaker-model update and plan shift that ``mpc_tick`` does.
* C: :func:`impact_env.control.mpc.c_text.solver_c` is the same solver in C99 (file-scope
  static functions, ``mpc_tick(x1, v1, x2, v2, k, mem)``), bitwise the kernel in double.
* counters: ``mem[solver.MEM.fallbacks]`` (non-finite state or result: the previous plan's
  input was used), ``mem[solver.MEM.no_descent]`` (iterations that found no lower cost).
"""
