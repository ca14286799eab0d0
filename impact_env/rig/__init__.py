"""The hardware adapter for the physical rig of thesis ch. 4 (and its virtual twin), in three rooms
that talk through public interfaces only:

* the **target** (runs beside the rig; imports no gymnasium and no env layer):
  :mod:`~impact_env.rig.target` (the server: sessions, ARM, uploads, fetches),
  :mod:`~impact_env.rig.episode` (one episode's tick loop and the host's commands; it asks its
  target through ``Target.reply``, ``serve_fetch``, ``info``, ``queue_arm``,
  ``close_session_after_episode`` and ``stopping``), :mod:`~impact_env.rig.controller` (the
  compiled tick: front end, policy, residual law, safety, log row), :mod:`~impact_env.rig.safety`
  (watchdog, force clamps, travel limit, non-finite commands), :mod:`~impact_env.rig.driver`
  (the rig's driver interface and the virtual rig), :mod:`~impact_env.rig.cycles` (tick pacing), :mod:`~impact_env.rig.excitation`;
* the **host** (the Gymnasium side: the one module here that imports the env layer):
  :mod:`~impact_env.rig.host` (``RigClient`` and ``ImpactCatchRig-v0``, whose task is
  :mod:`impact_env.env.task`'s);
* **log analysis** (offline): :mod:`~impact_env.rig.log` (the per-tick log and its HDF5 file;
  h5py is the optional extra ``impact-env[rig]``), :mod:`~impact_env.rig.flight_energy` (body 1's
  energy from the flight times, thesis eq 4.5), :mod:`~impact_env.rig.log_metrics` (compare's
  metrics of a logged episode), :mod:`~impact_env.rig.log_plot`.

Shared by target and host: :mod:`~impact_env.rig.protocol` (the UDP wire format: versioned binary
layout, HMAC-SHA256 tag, and the receiver-side ``DatagramFilter``),
:mod:`~impact_env.rig.transport` (a loopback-testable UDP endpoint, ``udp://HOST:PORT``
addresses, ``Link``, ``RigTimeout``), :mod:`~impact_env.rig.auth` and
:mod:`~impact_env.rig.errors` (the one :class:`~impact_env.rig.errors.RigError`).
"""
