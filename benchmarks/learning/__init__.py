"""The learning suite: a grid of recipe runs (cells × variants × seeds) and its report.

``python -m benchmarks.learning`` (``__main__.py``, the driver in ``suite.py``); the grid is
``cells.py`` and ``variants.py``, where the runs execute ``backends.py``, their cost
``cost.py``; the report ``report.py`` (statistics ``stats.py``, paired comparisons
``pairs.py``, figures ``plots.py``, the paper's tables ``paper_tables.py``); the reference
implementations' runs ``reference_d3rlpy.py`` (+ ``reference_learners.py``).
"""
