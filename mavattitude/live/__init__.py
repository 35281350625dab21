"""Live: watch a vehicle over a MAVLink link, estimate as its samples arrive, record everything.

``session.run_live`` is the loop ``mavattitude live`` runs; ``link`` opens the connection and
asks for rates; ``estimation`` steps replay's estimators on the arriving samples; ``display``
streams to Rerun and draws the status line; ``recorder`` writes the .tlog.
"""
from .session import LiveOptions, LiveResult, default_record_path, run_live

__all__ = ["LiveOptions", "LiveResult", "default_record_path", "run_live"]
