"""Run the benchmark modules in bench/ (``make bench`` / ``python -m bench [NAME ...]``).

Without names, every module except the long ones (``bench_scale``: the 100x run, about 10 minutes;
``make bench-scale``).
"""

import importlib
import pkgutil
import sys
from pathlib import Path

here = Path(__file__).parent
only = sys.argv[1:]
LONG = {"bench_scale"}
for m in sorted(pkgutil.iter_modules([str(here)]), key=lambda m: m.name):
    if not m.name.startswith("bench_") or (only and m.name not in only) or (not only and m.name in LONG):
        continue
    print(f"== {m.name}")
    importlib.import_module(f"bench.{m.name}").main()
