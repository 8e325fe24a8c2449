"""The measuring library: how every moving command measures a reflector with the rig.

* ``search``: finding normal incidence — the acquisition raster's lines, the centring sweeps
  and the fit of static probes with the piston's directivity (``PeakSearch``), the water path
  there (``read_distance``);
* ``face``: one face of the block at normal incidence from a predicted posture, searched as
  hard as the prediction deserves (``measure``, ``SearchMode``);
* ``acquire``: the noise floor in open water, the acquisition gain and the raster, one
  ``Raster`` per kind of reflector (the block's faces, the tool-frame plate);
* ``edges``: the scan across a reflector's straight edge (the plate's, the block's), one set
  of settings (``EDGES``);
* ``running``: measure a face, refit the cell, predict the next posture, decide how far to
  trust the prediction — one loop (``RunningEstimate``) and one policy (``Trust``) for
  calibrate (both levels), check and verify — and the check of a predicted posture before the
  robot moves there;
* ``approach``: every static posture reached with each joint moving up (``FinalApproachRig``).

Each face measurement carries the sign of each joint's last motion before its water path was
read (``approach``) and the minutes since the run's first reading (``time_min``), for the
solvers' lost-motion and drift unknowns. The procedures (``ucal.calibration``,
``ucal.verify``, ``ucal.toolframe``, ``ucal.check``) say which posture to measure next and
from where.
"""
