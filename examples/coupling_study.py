"""Coupling-scheme comparison study (the same as ``gelcell study``).

    .venv/bin/python examples/coupling_study.py --quick --out results/study-quick --update-table docs/coupling-study.md
    .venv/bin/python examples/coupling_study.py --out results/study            # the full study (a benchmark)
"""

import sys

from gelcell.cli import main

if __name__ == "__main__":
    sys.exit(main(["study"] + sys.argv[1:]))
