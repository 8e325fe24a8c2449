"""``ucal check``: a short check of the cell against what its commissioning recorded.

* ``plan``: the postures (a few of calibrate's normal-incidence measurements) and the echo
  chain, the reference to compare against, the real-cell duration;
* ``measure``: calibrate's face measurements of those postures, then the echo chain (time of
  flight, amplitude, SNR, the A-scan's centre frequency and bandwidth), then the edges;
* ``edges``: the scans across the XY face's far edges (the tool across the beam) and their
  rows in the fit;
* ``observe``: what each measurement sees and which quantities the postures determine;
* ``solve``: what moved — the check and the reference in one fit on the profile's model, the
  stepwise choice of the suspects that explain the data;
* ``profile_fit``: the first check of a profile, its faces against the calibration it holds;
* ``judge``: every checked quantity (geometry, water, echo chain) against its 3σ and its
  tolerance: moved, ok or not determined;
* ``causes``: what moved as causes with their sizes (the tool across or along its beam);
* ``growth``: the arm grown by a warm-up (every DH length by one factor) as a suspect;
* ``result``: the typed result, the message naming what moved, the history entry;
* ``history``: the checks in the profile's history directory (``checks.json``);
* ``procedure``: the command's job on the measuring procedure (``ucal.procedure``).

With the tank thermometer's log (``check --thermometer``) the procedure takes the tank's turns
out of the check's water paths and gives its drift the log's prior, as for calibrate
(``ucal.thermometer``); the history entry keeps what the log gave, and a later check fits the
reference's run with it (``solve``).
"""
