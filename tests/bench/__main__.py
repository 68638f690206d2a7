"""`python -m tests.bench [name ...]`: run benchmark modules, print tables, write out/bench-report.json."""

from __future__ import annotations

import importlib
import json
import pkgutil
import sys
import time
from pathlib import Path

import tests.bench as package


def main(argv: list[str]) -> int:
    names = argv or sorted(
        m.name for m in pkgutil.iter_modules(package.__path__) if m.name.startswith("bench_")
    )
    report = {"date": time.strftime("%Y-%m-%d %H:%M:%S"), "sections": []}
    for name in names:
        module = importlib.import_module(f"tests.bench.{name}")
        for section in module.run():
            print(section.table(), flush=True)
            report["sections"].append(
                {"module": name, "title": section.title, "rows": section.rows, "notes": section.notes}
            )
    out = Path("out/bench-report.json")
    out.parent.mkdir(exist_ok=True)
    out.write_text(json.dumps(report, indent=2, default=float))
    print(f"report written to {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
