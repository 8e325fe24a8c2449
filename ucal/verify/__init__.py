"""``ucal verify``: the positioning error before and after calibration (paper 000, §5.2), and the
region check (``--region N``).

* ``inputs``: what the profile's files say beside its model: the offsets and block pose before
  its last calibration, the sound speed, how J1 was calibrated;
* ``plan``: the nominal points in three orientations of the tool, the commanded postures of
  both passes, checked before the first motion;
* ``measure``: each point's three normal-incidence postures and water paths, then the tool
  check across the XY face's far edges;
* ``solve``: the reconstruction (wrist centre, flange orientation, reached TCP, the tool's
  error) and the statistics of paper 000, Table 5;
* ``result``: the typed result the tables, the picture and ``--json`` are drawn from;
* ``picture``: the picture verify writes beside the profile;
* ``region``: the region check, the kinematic model over spread postures (its result in
  ``result``);
* ``procedure``: the command's job on the measuring procedure (``ucal.procedure``).

The method and what the figures mean: docs/method/commissioning.md.
"""

from ucal.verify.measure import VerifyResult
from ucal.verify.picture import PICTURE_SUFFIX, verify_picture_path
from ucal.verify.procedure import VerifyJob
from ucal.verify.region import RegionJob
from ucal.verify.result import RegionCheck, RegionResult, Verification, VerifySolved

__all__ = [
    "PICTURE_SUFFIX",
    "RegionCheck",
    "RegionJob",
    "RegionResult",
    "Verification",
    "VerifyJob",
    "VerifyResult",
    "VerifySolved",
    "verify_picture_path",
]
