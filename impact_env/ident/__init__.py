"""System identification: a scene fitted to a rig from its own episode logs.

* :mod:`~impact_env.ident.plan`: the identification plan (quiet, shaker-only and identification-
  drop episodes, how many of each and why) and running it on a target (``impact-env rig identify``);
* :mod:`~impact_env.ident.experiments`: logs read back as experiments (the commands the DAC held,
  the raw readings), refused with their cause when they cannot serve;
* :mod:`~impact_env.ident.model`: the project's own hardware stage replaying an experiment for
  many candidate scenes at once;
* :mod:`~impact_env.ident.fit`: the staged least-squares fit, its uncertainties and what the
  logs cannot separate;
* :mod:`~impact_env.ident.report`: the calibrated scene file (``base = ...``, values with their
  uncertainties and sources in comments), the report and its figures.
"""
