"""Joint zero-offset calibration (paper 000): measurement model, solvers, procedure."""
