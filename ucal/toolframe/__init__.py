"""Tool-frame calibration: the transducer's centre and beam relative to the flange.

``plane`` fits the reflector plate's plane to touched points; ``paper`` is paper 002's
constrained least-squares formulation; ``exact`` is ours (beam from normal incidence, offset
along the beam from time of flight, offsets across the beam from edge reversal);
``procedure`` plans, checks and measures with the rig.
"""
