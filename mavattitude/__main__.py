import os
import sys

from . import signals

signals.install()  # before the imports: a Ctrl-C in the first second is one line too
try:
    from .cli import main
except KeyboardInterrupt:
    print(signals.message(), file=sys.stderr, flush=True)
    os._exit(signals.exit_code())  # not through the interpreter's exit, which a second Ctrl-C could cut

sys.exit(main())
