"""Run every benchmark module in bench/ (``make bench`` / ``python -m bench``)."""

import importlib
import pkgutil
import sys
from pathlib import Path

here = Path(__file__).parent
only = sys.argv[1:]
for m in sorted(pkgutil.iter_modules([str(here)]), key=lambda m: m.name):
    if not m.name.startswith("bench_") or (only and m.name not in only):
        continue
    print(f"== {m.name}")
    importlib.import_module(f"bench.{m.name}").main()
