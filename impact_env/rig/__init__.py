"""The hardware adapter for the physical rig of thesis ch. 4 (and its virtual twin).

Modules (each small and documented; nothing here imports gymnasium or the env layer):

* :mod:`~impact_env.rig.protocol`: the UDP wire format (versioned binary layout, HMAC-SHA256 tag) and the
  receiver-side :class:`~impact_env.rig.protocol.DatagramFilter` that drops and counts bad datagrams.
* :mod:`~impact_env.rig.transport`: a loopback-testable UDP endpoint, ``udp://HOST:PORT``
  addresses, :class:`~impact_env.rig.transport.Link` (sequence numbers, filtering, reliable
  requests with bounded retries) and :class:`~impact_env.rig.transport.RigTimeout`.
* :mod:`~impact_env.rig.safety`: the target's safety layer (watchdog, force clamps, travel
  limit, non-finite commands) as a numba kernel with a validated config.
* :mod:`~impact_env.rig.clock`: real-time tick pacing with absolute deadlines, and lock-step.
* :mod:`~impact_env.rig.log`: the per-tick episode log (preallocated, numba-friendly) and its
  HDF5 file (written atomically); h5py is the optional extra ``impact-env[rig]``.
* :mod:`~impact_env.rig.energy`: body 1's energy from the flight times between contacts (thesis
  eq 4.5) and a log summary with the metrics of ``impact-env compare``.
"""
