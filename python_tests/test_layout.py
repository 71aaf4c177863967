"""The package's layout (docs/architecture.md, "The Python package, by route"): what is installed is the
source tree."""

from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_installed_package_has_every_module():
    """The installed msx has every module of the source tree (mitsuba_plugin/msx/), sub-packages included: a
    package folder missing from the build's package list would be absent from the wheel."""
    import msx

    source = ROOT / "mitsuba_plugin" / "msx"
    installed = Path(msx.__file__).resolve().parent
    missing = [str(p.relative_to(source)) for p in sorted(source.rglob("*.py"))
               if "__pycache__" not in p.parts and not (installed / p.relative_to(source)).exists()]
    assert not missing, f"not installed (in {installed}): {missing}"
