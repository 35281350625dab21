"""mavattitude: replay MAVLink flight logs through attitude estimators and compare them
with the autopilot's own attitude and simulator ground truth."""
__version__ = "0.1.0"
