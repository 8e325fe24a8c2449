"""Digitisers: the A-scan as a separate instrument gives it (an oscilloscope over SCPI/VISA).

``base`` holds the record a digitiser returns and the host-side echo timing contract,
``scpi`` the SCPI framing every family shares (IEEE 488.2 blocks, the preamble's numbers, sample
codes), ``dialects`` each scope family's own commands as a table (Keysight InfiniiVision
X-Series, Rigol DS1000Z), ``visa`` the oscilloscope client over PyVISA that follows its
family's table, ``visa_transport`` its bytes, ``urls`` the ``visa://RESOURCE`` URL, and
``scpi_simulator`` a simulated oscilloscope on 127.0.0.1 of either family
(``simulated_scopes``: the families as data) whose signal is injected.
"""
