import sys

try:
    from .cli import main
except KeyboardInterrupt:   # before fusion.cli could say it (its own imports say it themselves)
    print("error: interrupted", file=sys.stderr)
    sys.exit(130)

sys.exit(main())
