"""``python -m benchmarks.learning``: the learning suite's command line (``suite.py``)."""

import sys

from benchmarks.learning.suite import main

if __name__ == "__main__":
    sys.exit(main())
