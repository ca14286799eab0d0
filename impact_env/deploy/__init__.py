"""Deploying a policy outside Python: one dependency-free C99 file that does what the rig
target's tick does between the DAQ readings and the drive command (:mod:`impact_env.deploy.c_export`),
a real-time Linux example around it (``impact_env/deploy/rt/``), and the parity check that
proves a build equal to the simulator's kernels (:mod:`impact_env.deploy.parity`)."""
