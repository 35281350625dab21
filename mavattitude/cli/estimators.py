"""``mavattitude estimators``: every estimator with its parameters, defaults and diagnostics."""
from __future__ import annotations

import json


def add_parser(sub) -> None:
    p = sub.add_parser("estimators", help="list the estimators with their parameters and defaults",
                       description="List every estimator: the paper it follows, whether it uses the "
                                   "magnetometer, its parameters with defaults and units, and the "
                                   "diagnostics it records.")
    p.add_argument("--json", action="store_true", help="print the list as JSON")
    p.set_defaults(func=run)


def run(args) -> int:
    from ..estimators import ESTIMATORS, available, summary
    from ..estimators.rivals import INSTALL
    from ..core.params import describe, search_space

    if args.json:
        print(json.dumps({name: {"summary": summary(cls), "uses_magnetometer": cls.uses_mag,
                                 "params": {f: {"default": d, "valid": str(v) if v else None, "help": h,
                                                "tune": str(search_space(cls.Params)[f])
                                                if f in search_space(cls.Params) else None}
                                            for f, d, v, h in describe(cls.Params)},
                                 "diagnostics": dict(cls.DIAGNOSTICS),
                                 "accel_states": list(cls.ACCEL_STATES)}
                          for name, cls in ESTIMATORS.items()}, indent=2))
        return 0
    for name, cls in ESTIMATORS.items():
        heading = "heading from the magnetometer" if cls.uses_mag else "no heading reference (yaw from the gyro)"
        optional = f" (optional: {INSTALL}; not installed)" if available(name) else ""
        print(f"{name}: {summary(cls)}{optional}")
        print(f"  {heading}")
        rows = describe(cls.Params)
        searched = search_space(cls.Params)
        width = max((len(f) for f, _, _, _ in rows), default=0)
        for field, default, valid, help_text in rows:
            tune = f"  [tune: {searched[field]}]" if field in searched else ""
            print(f"  --set {name}.{field:<{width}} = {default!s:<8} {str(valid or 'true/false'):<11} "
                  f"{help_text}{tune}".rstrip())
        for key, text in cls.DIAGNOSTICS.items():
            print(f"  diagnostic {key}: {text}")
        print()
    print("Override parameters with --set NAME.PARAM=VALUE or a TOML file (--params FILE) with a "
          "[NAME] table per estimator; each value must lie in the interval shown after its default. "
          "'mavattitude tune' searches the parameters marked [tune: scale [low, high]].")
    return 0
