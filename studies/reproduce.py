"""Regenerate one of the paper's tables or figures: ``python studies/reproduce.py NAME [--quick]``.

The same as ``jko-cvx reproduce NAME [--quick]`` (see :mod:`jko_cvx.studies.reproduce`); writes to
``studies/results/reproduce/`` unless ``--out`` says otherwise.
"""

import sys

from jko_cvx.cli import main

if __name__ == "__main__":
    args = sys.argv[1:]
    if "--out" not in args:
        args += ["--out", "studies/results/reproduce"]
    sys.exit(main(["reproduce", *args]))
