"""The demo truth: the hidden errors of the built-in simulated cell (``--sim`` without a world).

The demo truth is the profile's nominal cell plus errors a commissioning engineer would meet:

- joint zero offsets (0.8, −1.2, 1.5, −2.0, 1.1, 0.6)° (actual = reading + offset);
- a tool frame off by (0.3, −0.2, 0.4) mm with the beam tilted about 0.3° (rx 0.2°, ry −0.22°);
  whether a calibration can see joint 6 depends on that tilt (with a beam exactly along the
  flange axis joint 6 does not move it);
- the calibration block 1.5, −1.0, 0.8 mm off its nominal corner (orientation nominal);
- TOF noise 0.5 ns and amplitude noise 1 % (one sigma per reading), seed 20240611.

The robot's DH table, the water temperature, the transducer and the reflector plate are nominal.

The truth is one cell whatever ucal writes into the profile, and whatever became of its
history: the errors are added to the cell as the profile describes it
(``CellProfile.as_described``: the tool as drawn, the ``[robot]`` table, the block as placed,
which ``tool-frame`` and ``calibrate`` keep beside what they measured,
``ucal.profile.described``), not to the tool, the identified table or the block they wrote.
Built from the measured values instead, the demo tool would move by the demo's error every time
``tool-frame`` wrote its (right) estimate, and a ``calibrate`` run after it would meet a cell
0.3° away from what the profile rightly says; the block would move by its 1.9 mm each time
``calibrate`` wrote where it found it. A hand edit of the tool or the block is a new
description, and the demo follows it.

The block's yaw is as placed: the commissioning on this cell ends with ``verify`` passing
relative to the block (J1 relative to the block as placed, ``ucal.model.gauge``), and
``examples/faulty_world.toml`` is this cell with faults, for a ``verify`` that fails.
"""

from __future__ import annotations

import numpy as np

from ucal.cell import CellProfile, Noise, WorldTruth

DEMO_JOINT_OFFSETS_DEG = np.array([0.8, -1.2, 1.5, -2.0, 1.1, 0.6])
DEMO_TOOL_POSITION_ERROR_MM = np.array([0.3, -0.2, 0.4])
DEMO_TOOL_ROTATION_ERROR_DEG = np.array([0.2, -0.22, 0.0])
DEMO_SAMPLE_POSITION_ERROR_MM = np.array([1.5, -1.0, 0.8])
DEMO_NOISE = Noise(tof_ns=0.5, amplitude=0.01, seed=20240611)


def demo_world(profile: CellProfile) -> WorldTruth:
    """The demo truth of ``profile``: its cell as described, with the hidden errors of this
    module."""
    nominal = WorldTruth.nominal(profile.as_described())
    return nominal.replace(
        joint_offsets_deg=DEMO_JOINT_OFFSETS_DEG.copy(),
        tool_position_mm=nominal.tool_position_mm + DEMO_TOOL_POSITION_ERROR_MM,
        tool_rotation_deg=nominal.tool_rotation_deg + DEMO_TOOL_ROTATION_ERROR_DEG,
        sample_position_mm=nominal.sample_position_mm + DEMO_SAMPLE_POSITION_ERROR_MM,
        noise=DEMO_NOISE,
    )
