"""The Rerun view of a replay: one recording per replay, laid out by a blueprint.

Everything time-varying goes through ``rr.send_columns`` (one call per entity and chunk of
samples); ``rec.log`` is used only for static styling, the summary and the GPS track. The
helpers take a chunk of samples and always write the same entity paths, so a live session
(estimates arriving in chunks) reuses ``send_blueprint``, ``setup_series`` and the
``log_*_columns`` functions unchanged.

Timeline: ``"time"``, a duration in seconds on the autopilot clock (seconds since boot).

Entity paths (``<s>`` is a series key: ``autopilot``, ``truth``, ``reference`` when the
reference is neither of those, one of the autopilot's other streams (``autopilot:EKF1 (EKF1)``),
or an estimator's name, escaped for entity paths):

- ``attitude/{roll,pitch,yaw}/estimates/<s>``, ``attitude/{roll,pitch,yaw}/reference/<s>`` (the
  autopilot and its streams, truth: drawn on top)  Scalars, degrees (+ static SeriesLines: colour, label)
- ``error/{roll,pitch,yaw}/<s>``  Scalars, estimate - reference, degrees, scored samples
- ``error/{roll,pitch,yaw}/_unscored/<s>``  the samples the statistics skip (warm-up), faded;
  named as the scored line, so the legend has one entry for both (the viewer merges equal
  names; its dot shows the faded colour)
- ``world``  static ViewCoordinates FRD: the 3D world is NED (x north, y east, z down)
- ``world/<s>``  static Transform3D: the series' slot, ``SLOTS_PER_ROW`` side by side along
  east, further rows behind (north)
- ``world/<s>/body``  Transform3D quaternion column (body -> NED), static Boxes3D + axes
- ``world/<s>/label``  static Points3D carrying the series' name above its box
- ``world/<s>/reference``  the reference attitude again, as a grey wireframe "ghost" in
  every other slot, so an estimate's error is visible as the gap between box and ghost
- ``map/track``  static GeoLineStrings of the GPS track; ``map/position`` GeoPoints over time
- ``map/estimate/<s>``  static GeoLineStrings of an estimator's own track (``pos_n``/``pos_e``
  diagnostics, NED around the first GPS fix), ``map/estimate/<s>/position`` GeoPoints over time
- ``track``  static ViewCoordinates FRD (NED); ``track/gps`` and ``track/<s>``: static LineStrips3D
  of the GPS track and the estimated track, metres from the first fix (a "track" tab)
- ``events``  TextLog of the replay's events (and one metrics line per comparison at the end)
- ``diagnostics/<key>/<s>``  Scalars: what each filter exposes (``cov_trace``, ``adaptive_r``,
  ``accel_weight``, ...), peak-preserving like the errors; ``accel_state`` is the filter's
  accelerometer state code over time (0 used; see ``mavattitude estimators`` for the codes).
  Keys of one vector, ``<group>_<axis>`` with the axis x, y, z or n, e, d (``gyro_bias_x``,
  ``vel_n``), share a plot: ``diagnostics/<group>/<s>/<axis>``
- ``phase/in_air``, ``phase/height``  the ground/air phase (1 = air) and the height above the
  start it comes from
- ``summary``  static TextDocument (markdown): the flight and the metrics table

Decimation (what the viewer gets; the metrics are always computed on every sample):

- attitude scalars: every sample while a series' mean rate is <= ``SCALAR_MAX_HZ`` (200 Hz);
  faster series keep the first sample of each 1/200 s bin. Long logs are further capped at
  ``SCALAR_MAX_POINTS`` per series (the rate becomes ``SCALAR_MAX_POINTS / duration``:
  200 Hz up to 20 min, 67 Hz for an hour);
- error scalars: the same rate, but peak-preserving: the minimum and the maximum of each
  bin of two output samples, so no error spike disappears;
- 3D transforms: at most ``TRANSFORM_MAX_HZ`` (50 Hz), first sample per bin, and at most
  ``TRANSFORM_MAX_POINTS`` per series (50 Hz up to 30 min, 25 Hz for an hour);
- GPS marker at most ``GPS_MARKER_MAX_HZ`` (10 Hz); the static track at most
  ``GPS_TRACK_MAX_POINTS`` points.

Bins are on absolute time (``floor(t * hz)``) and a chunk's first sample counts as opening a
bin only if one sample step earlier lies in another bin, so a regularly sampled series sent in
chunks keeps the same samples as sent whole (min/max bins straddling a chunk boundary may add
a point or two).
"""
from .blueprint import *  # noqa: F401,F403
from .blueprint import _TEXT_LOG_COLUMNS, _diagnostics_tab  # noqa: F401
from .columns import *  # noqa: F401,F403
from .columns import (_bin_first, _bin_minmax, _break_lines, _gps_fix, _send_scalars, _thin,  # noqa: F401
                      _time)
from .replay import *  # noqa: F401,F403
from .marks import *  # noqa: F401,F403
from .ranges import *  # noqa: F401,F403
from .replay import _plotted_diagnostics, _reference_key, _scored, _series, _summary_events  # noqa: F401
from .style import *  # noqa: F401,F403
from .style import _part  # noqa: F401
