"""Tool-frame calibration: the transducer's centre and beam relative to the flange.

``plane`` fits the reflector plate's plane to touched points; ``paper`` is paper 002's
constrained least-squares formulation; ``exact`` is ours (beam from normal incidence, offset
along the beam from time of flight, offsets across the beam from edge reversal);
``fit`` solves those measurements again with the joint offsets, the plate, the DH table, the
sound speed and an electronic delay as unknowns with the profile's tolerances as priors (what a
run reports and writes). The command over them, of the shape of every procedure package:
``plan`` (the targets, checked before the first motion), ``measure`` (the postures and edge
scans with the rig), ``solve`` (the tool frame from the measurements), ``result`` (the
``[tool]`` keys, the refusal, the typed result the tables and ``--json`` are drawn from) and
``procedure`` (the command's job on ``ucal.procedure``).
"""
