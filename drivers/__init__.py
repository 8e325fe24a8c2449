"""Hardware drivers and their simulated backends.

``drivers`` never imports ``ucal``: the arrow points from the application to the hardware.
Interfaces (``drivers.controller.base``, ``drivers.pulser.base``) speak degrees, millimetres
and nanoseconds; radians and metres appear only inside the controller wire protocol.
"""
