"""Results published for a factory: a cell's results to an MQTT broker, and the fleet's view.

- :mod:`ucal.fleet.url`: the broker URL ``mqtt://HOST[:PORT]/PREFIX`` and the topics under it;
- :mod:`ucal.fleet.message`: the published message (schema version 1, ``result-v1.json``):
  the cell, the profile's hash, ucal's version, the time, the command's result and the
  calibration-target fields (last and next validation date, quality);
- :mod:`ucal.fleet.outbox`: the cell's durable queue (``PROFILE.history/outbox/``): one file per
  message, in order, removed only once the broker acknowledged it;
- :mod:`ucal.fleet.mqtt`: the broker link (paho-mqtt, QoS 1) and the reading of the cells'
  retained states;
- :mod:`ucal.fleet.publish`: a run's result queued and the queue delivered, never changing the
  run's outcome;
- :mod:`ucal.fleet.view`: the fleet's table (cells, last results, due dates, trends).

docs/fleet.md documents the topics, the payload and the queue. Nothing here is imported at
start-up: paho-mqtt is loaded only when something is published or read.
"""
