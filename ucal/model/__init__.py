"""The cell model every command fits: the measurement model (``geometry``), the priors and the
parameter table (``priors``), the residuals, the least squares and its fit quality, the J1
gauge, the wrist's aim, the planning margins (``safety``, ``spread``) and the kept readings.
It imports no procedure: ``calibration``, ``toolframe``, ``verify`` and ``check`` stand on it.
"""
