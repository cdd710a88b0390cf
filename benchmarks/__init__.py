"""usdahd-bench: the benchmark harness of the usdahd checkout (benchmarks/pyproject.toml).

A development package: ``pip install -e benchmarks/`` from a clone, after usdahd. Its scripts
import their siblings by file name (``import common``), as ``python benchmarks/run.py`` always
has; ``benchmarks.run`` puts this folder on ``sys.path`` for them.
"""
