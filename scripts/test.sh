#!/usr/bin/env bash
# Install (scripts/install.sh), lint (ruff, the rules of pyproject.toml) and run the test suite, slow tests and
# docstring examples included.
# A quick run leaves out the tests marked slow: bash scripts/test.sh -m "not slow"
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install.sh
. .venv/bin/activate
python -m ruff check src tests benchmarks scripts
python -m pytest -p no:cacheprovider "$@"
