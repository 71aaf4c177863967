#!/usr/bin/env bash
# Runs every test: installs the package (builds the Rust library and the cffi
# extension), then the Rust tests (unit, statistical, C consumer, header check)
# and the Python plugin tests inside Mitsuba.
set -euo pipefail
cd "$(dirname "$0")/.."
python3 -m pip install --quiet --disable-pip-version-check '.[test]'
cargo test --quiet
python3 -m pytest python_tests -q
