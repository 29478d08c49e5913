import sys

try:
    from .cli import main
except KeyboardInterrupt:   # before fusion.cli could say it (its own imports say it themselves)
    import os

    print("error: interrupted", file=sys.stderr)
    sys.stderr.flush()
    os._exit(130)           # at once, as fusion.cli does (fusion.cli._interrupted_while_loading)

sys.exit(main())
