#!/usr/bin/env bash
# Create the separate virtual environment for bench/pyrecest_compare.py (issue 4).
#
# pyrecest is NOT a dependency of fgloc and must never be installed into the main
# environment. This venv sees the main environment's packages (--system-site-packages,
# so `import fgloc`, numpy, scipy, ... resolve to the main install) and adds pyrecest
# (pinned) plus the few extra dependencies it needs on top of that.
#
# Usage:  bash bench/pyrecest_env.sh            # venv at bench/.venv-pyrecest (default)
#         PYRECEST_VENV=/tmp/venv-pyrecest bash bench/pyrecest_env.sh
# Then:   PYRECEST_BACKEND=numpy bench/.venv-pyrecest/bin/python bench/pyrecest_compare.py
set -euo pipefail

PYRECEST_VERSION="2.4.2"
HERE="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
VENV="${PYRECEST_VENV:-$HERE/.venv-pyrecest}"
PY="${PYTHON:-python3}"

if [ ! -x "$VENV/bin/python" ]; then
    "$PY" -m venv --system-site-packages "$VENV"
fi
# Install pyrecest with its dependencies into the venv only. pip keeps the main
# environment's numpy/scipy/matplotlib when they already satisfy pyrecest's pins
# (numpy>=2.0,<2.5, scipy>=1.14,<1.18, matplotlib>=3.8,<4); anything it has to add
# or upgrade (beartype, shapely, pyshtools, ...) lands in the venv's own site-packages.
"$VENV/bin/python" -m pip install --quiet "pyrecest==${PYRECEST_VERSION}"

# Sanity checks: numpy backend, the tracker class, and fgloc from the main install.
PYRECEST_BACKEND=numpy "$VENV/bin/python" - <<'PYEOF'
import numpy, scipy
import fgloc
import pyrecest
from pyrecest.filters import FullSCGPTracker  # noqa: F401
import pyrecest.backend as be
print("venv ok: pyrecest", pyrecest.__version__ if hasattr(pyrecest, "__version__") else "?",
      "backend", getattr(be, "__backend_name__", "?"),
      "numpy", numpy.__version__, "scipy", scipy.__version__, "fgloc", fgloc.__file__)
PYEOF
echo "venv: $VENV"
