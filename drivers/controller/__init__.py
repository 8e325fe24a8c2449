"""Robot controller drivers: interface, Simple Message client, simulated VAL3-style server."""
