"""Pulser-receiver drivers: interface, Modbus RTU/TCP client and simulated server, ASCII serial
pulser (with a digitiser) and its simulator."""
