"""Shared test fixtures: the toy FMUs."""
import pytest


@pytest.fixture(scope="session")
def toy_dir(tmp_path_factory):
    """The toy FMUs of tests/fmus, built once per session."""
    from orchestration.build import build_all
    from toys import TOYS
    dest = tmp_path_factory.mktemp("toy_fmus")
    build_all(dest, quiet=True, scripts=sorted(TOYS.glob("*_fmu.py")))
    return dest


@pytest.fixture
def toy_fmus(toy_dir, monkeypatch):
    """Scenarios find their FMUs among the toys (``pytestmark = usefixtures("toy_fmus")``)."""
    monkeypatch.setenv("FLEXFUSION_FMU_DIR", str(toy_dir))
