"""``python -m selfsupport``: the command line (see :mod:`selfsupport.cli`)."""
import sys

try:  # Ctrl-C while numpy & co. are still importing: the same one line as later on
    from selfsupport.cli.common import console_main
except KeyboardInterrupt:
    print("selfsupport: interrupted; nothing was written", file=sys.stderr)
    sys.exit(130)

console_main()
