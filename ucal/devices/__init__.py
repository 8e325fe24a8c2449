"""The cell's devices as the procedures use them, over the drivers of ``drivers/``.

- :mod:`ucal.devices.rig`: the rig: the robot and the pulser-receiver moved and read together
  (moves, reads, sweeps, each joint's last motion, the run's clock);
- :mod:`ucal.devices.session`: a cell, opened: real (its URLs), simulated (``--sim``) or replayed
  (``--replay``), with its echo timing and the STOP on every exit;
- :mod:`ucal.devices.record`: the record of a run (``--record``): the device traffic and the
  measurements, which a replay plays back.
"""
