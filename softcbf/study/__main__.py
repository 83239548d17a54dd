"""`python -m softcbf.study run|report …` (see softcbf.study.cli)."""

import sys

from softcbf.study.cli import main

if __name__ == "__main__":
    sys.exit(main())
