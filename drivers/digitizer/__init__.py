"""Digitisers: the A-scan as a separate instrument gives it (an oscilloscope over SCPI/VISA).

``base`` holds the record a digitiser returns and the host-side echo timing contract,
``scpi`` the SCPI framing (IEEE 488.2 blocks, the waveform preamble, sample codes), ``visa`` the
oscilloscope client over PyVISA, ``urls`` the ``visa://RESOURCE`` URL and ``scpi_simulator`` a
simulated oscilloscope on 127.0.0.1 whose signal is injected.
"""
