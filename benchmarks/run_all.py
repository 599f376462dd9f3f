"""Run every benchmark in this directory (full problem sizes; takes minutes), then rewrite the README's numbers.

The README quotes the results through generated blocks (benchmarks/readme_tables.py): after the
benchmarks have written benchmarks/results/, the blocks are re-rendered from them.
"""

from __future__ import annotations

import runpy
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent

if __name__ == "__main__":
    for script in sorted(HERE.glob("bench_*.py")):
        print(f"\n## {script.stem}\n", flush=True)
        sys.argv = [str(script)]
        runpy.run_path(str(script), run_name="__main__")
    print("\n## README\n", flush=True)
    sys.path.insert(0, str(HERE))
    import readme_tables

    sys.exit(readme_tables.main([]))
