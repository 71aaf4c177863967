#!/usr/bin/env bash
# Runs every test: installs the package (builds the Rust library and the cffi
# extension), then the Rust format check, lints and tests (unit, statistical,
# fuzz, C consumer, header check) and the Python plugin tests inside Mitsuba.
# Each step prints its progress: test names as they pass, skip reasons at the end.
set -euo pipefail
cd "$(dirname "$0")/.."
step() { printf '\n== %s (%s) ==\n' "$1" "$(date +%T)"; }

step "1/4 build and install msx with pip (cargo build --release inside)"
python3 -m pip install --disable-pip-version-check --progress-bar off '.[test]'

step "2/4 format and lints (cargo fmt --check; cargo clippy --all-targets -- -D warnings; ruff check)"
if cargo fmt --version >/dev/null 2>&1; then
    cargo fmt --check
else
    echo "skipped: rustfmt is not installed (rustup component add rustfmt)"
fi
if cargo clippy --version >/dev/null 2>&1; then
    cargo clippy --all-targets --quiet -- -D warnings
else
    echo "skipped: clippy is not installed (rustup component add clippy)"
fi
python3 -m ruff check .  # the Python lint of pyproject.toml (installed with the test extras)

step "3/4 Rust tests (cargo test)"
cargo test

step "4/4 Python plugin tests (pytest)"
python3 -m pytest python_tests -v -rs
