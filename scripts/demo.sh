#!/usr/bin/env bash
# Install (scripts/install.sh) and run the built-in demo.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install.sh
. .venv/bin/activate
mvm demo "$@"
