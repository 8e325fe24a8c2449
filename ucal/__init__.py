"""ucal: calibrate a six-axis robot with the ultrasonic transducer it carries."""

__version__ = "0.1.0"
