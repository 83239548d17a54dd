"""`python -m softcbf_mj.study run|report …` (see softcbf_mj.study.cli)."""

import sys

from softcbf_mj.study.cli import main

if __name__ == "__main__":
    sys.exit(main())
