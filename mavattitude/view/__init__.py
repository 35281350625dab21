"""The Rerun view of a replay: one recording per replay, laid out by a blueprint.

Everything time-varying goes through ``rr.send_columns`` (one call per entity and chunk of
samples); ``rec.log`` is used only for static styling, the summary and the GPS track. The
helpers take a chunk of samples and always write the same entity paths, so a live session
(estimates arriving in chunks) reuses ``send_blueprint``, ``setup_series`` and the
``log_*_columns`` functions unchanged.

Timeline: ``"time"``, a duration in seconds on the autopilot clock (seconds since boot).

Entity paths: one subtree per series, ``<root>`` = ``est/<s>`` for an estimate, ``ref/<s>``
for the reference, the autopilot and the truth, ``alt/<s>`` for the autopilot's other streams
(``<s>`` is the series key: ``autopilot``, ``truth``, ``reference`` when the reference is neither,
``autopilot:EKF1 (EKF1)``, or an estimator's name, escaped). Everything a series draws is under
its root, so hiding the root ("Hide in all views") hides it everywhere; every view lists the
roots it draws from (``blueprint._contents``). The plots draw in path order: ``alt``, ``est``,
then ``ref`` on top.

- ``<root>/attitude/{roll,pitch,yaw}``  Scalars, degrees (+ static SeriesLines: colour, label)
- ``<root>/error/{roll,pitch,yaw}``  Scalars, estimate - reference, degrees, scored samples
- ``<root>/warmup/{roll,pitch,yaw}``  the samples the statistics skip (warm-up), faded; named
  as the scored line, so the legend has one entry for both
- ``/``  static ViewCoordinates FRD: the 3D views are NED (x north, y east, z down)
- ``<root>/box``  static Transform3D: the series' slot, ``SLOTS_PER_ROW`` side by side along
  east, further rows behind (north); ``<root>/box/body`` Transform3D quaternion column (body ->
  NED), static Boxes3D + axes; ``<root>/box/label`` its name; ``<root>/box/reference`` the
  reference attitude as a grey wireframe "ghost" in every other slot
- ``map/track``  static GeoLineStrings of the GPS track; ``map/position`` GeoPoints over time
- ``<root>/map``  static GeoLineStrings of an estimator's own track (``pos_n``/``pos_e``
  diagnostics, NED around the first GPS fix), ``<root>/map/position`` GeoPoints over time
- ``track/gps``, ``<root>/track``  static LineStrips3D of the GPS and estimated tracks, metres
  from the first fix (a "track" tab)
- ``events``  TextLog of the replay's events (and one metrics line per comparison at the end)
- ``marks/{attitude,error}/<axis>/{warnings,phase}``  SeriesPoints at warnings and take-off /
  landing; ``marks/.../spans/<k>`` a translucent bar over each IMU gap and untrusted span of
  reference, named by what happened (the hover shows it)
- ``<root>/diagnostics/<group>[/<axis>]``  Scalars: what each filter exposes (``cov_trace``,
  ``adaptive_r``, ``accel_weight``, ...), min/max per bin at ``DIAGNOSTIC_MAX_HZ``;
  ``accel_state`` is the filter's accelerometer state code (0 used; ``mavattitude estimators``).
  Keys of one vector, ``<group>_<axis>`` with the axis x, y, z or n, e, d, share a plot
- ``phase/in_air``, ``phase/height``  the ground/air phase (1 = air) and the height above the
  start it comes from
- ``summary``  static TextDocument (markdown): the flight and the metrics table

Decimation (what the viewer gets; the metrics are always computed on every sample):

- attitude scalars: every sample while a series' mean rate is <= ``SCALAR_MAX_HZ`` (50 Hz);
  faster series keep the first sample of each 1/50 s bin. Long logs are further capped at
  ``SCALAR_MAX_POINTS`` per series (the rate becomes ``SCALAR_MAX_POINTS / duration``:
  50 Hz up to 20 min, 17 Hz for an hour);
- error scalars: the same rate, but peak-preserving: the minimum and the maximum of each
  bin of two output samples, so no error spike disappears;
- 3D transforms: at most ``TRANSFORM_MAX_HZ`` (25 Hz), first sample per bin, and at most
  ``TRANSFORM_MAX_POINTS`` per series (25 Hz up to 30 min, 12.5 Hz for an hour);
- GPS marker at most ``GPS_MARKER_MAX_HZ`` (10 Hz); the static track at most
  ``GPS_TRACK_MAX_POINTS`` points.

Bins are on absolute time (``floor(t * hz)``) and a chunk's first sample counts as opening a
bin only if one sample step earlier lies in another bin, so a regularly sampled series sent in
chunks keeps the same samples as sent whole (min/max bins straddling a chunk boundary may add
a point or two).
"""
import importlib

from .. import signals

# The view's names, from the module that defines them: loaded on first use (PEP 562), so that a
# command without a viewer (``live --no-record``, which imports ``view.sink``) never imports Rerun.
_MODULES = ("style", "ranges", "marks", "replay", "columns", "decimation", "blueprint")  # the first that has a name gives it


def import_rerun():
    """Rerun, imported with Ctrl-C held until it is in (``signals.holding_interrupts``): Rerun
    turns an exception raised while it builds its classes into a warning and goes on, so an
    interrupt then would be lost."""
    with signals.holding_interrupts():
        import rerun
        import rerun.blueprint  # noqa: F401
    return rerun


def __getattr__(name: str):
    if name.startswith("__"):
        raise AttributeError(name)
    import_rerun()
    for module in _MODULES:
        module = importlib.import_module(f".{module}", __name__)
        if hasattr(module, name):
            return getattr(module, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
