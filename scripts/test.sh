#!/usr/bin/env bash
# Install (scripts/install.sh) and run the test suite, slow tests and docstring examples included.
# A quick run leaves out the tests marked slow: bash scripts/test.sh -m "not slow"
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install.sh
. .venv/bin/activate
# ruff check src tests benchmarks scripts
python -m pytest -q -p no:cacheprovider "$@"
