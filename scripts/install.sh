#!/usr/bin/env bash
# Create .venv with mvm and its extras. torch is installed first and pinned by
# constraints.txt, so that no later step pulls a different (CUDA) build.
set -euo pipefail
cd "$(dirname "$0")/.."
python3 -m venv .venv
. .venv/bin/activate
python -m pip install -q --upgrade pip
python -m pip install -q torch==2.13.0
python -m pip install -q -c constraints.txt -e ".[net,detect,eval,dev,bench,ray]"
# An editable install leaves mvm's own modules to be compiled at each start where bytecode
# is not written (PYTHONDONTWRITEBYTECODE): compile them once, as pip does for a regular install.
python -m compileall -q src/mvm
