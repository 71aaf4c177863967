#!/usr/bin/env bash
# Runs every test: installs the package (builds the Rust library and the cffi
# extension), then the Rust tests (unit, statistical, fuzz, C consumer, header
# check) and the Python plugin tests inside Mitsuba. Each step prints its
# progress: test names as they pass, skip reasons at the end.
set -euo pipefail
cd "$(dirname "$0")/.."
step() { printf '\n== %s (%s) ==\n' "$1" "$(date +%T)"; }

step "1/3 build and install msx with pip (cargo build --release inside)"
python3 -m pip install --disable-pip-version-check --progress-bar off '.[test]'

step "2/3 Rust tests (cargo test)"
cargo test

step "3/3 Python plugin tests (pytest)"
python3 -m pytest python_tests -v -rs
