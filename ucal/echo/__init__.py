"""Echo timing on the host: time of flight and amplitude of an echo in a digitised A-scan.

``estimate_echo(ascan, reference)`` times one record against the cell's reference echo
(``ucal.echo.timing``: correlation, an unbiased sub-sample step, a std of the Cramér–Rao form
from the record's own SNR and the reference's bandwidth), or coarsely by its envelope without
one; a record with no echo to time (a constant, noise alone, an echo of the other polarity or
cut by the record's ends) raises ``NoEcho``, never a time. ``build_reference(captures)``
averages many captures into that reference, its arrival at t = 0 (``ucal.echo.reference``).
Records and their spectra: ``ucal.echo.ascan``.
"""

from ucal.echo.ascan import AScan, EchoBand, ReferenceEcho, echo_band, noise_rms
from ucal.echo.reference import build_reference, echo_arrival_ns
from ucal.echo.timing import (
    METHOD_ENVELOPE,
    METHOD_REFERENCE,
    EchoEstimate,
    NoEcho,
    delay_crb_ns,
    estimate_echo,
)

__all__ = [
    "METHOD_ENVELOPE",
    "METHOD_REFERENCE",
    "AScan",
    "EchoBand",
    "EchoEstimate",
    "NoEcho",
    "ReferenceEcho",
    "build_reference",
    "delay_crb_ns",
    "echo_arrival_ns",
    "echo_band",
    "estimate_echo",
    "noise_rms",
]
