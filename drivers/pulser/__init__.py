"""Pulser-receiver drivers: interface, Modbus RTU/TCP client, simulated Modbus server."""
