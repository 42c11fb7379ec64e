"""Shared test set-up: host pythonfmu FMUs safely in the test process (see fmpy_compat)."""
import orchestration.fmpy_compat as fmpy_compat


def pytest_unconfigure(config):
    """After pytest has reported everything, skip pythonfmu's crashing exit-time destructors."""
    status = getattr(config, "_flexfusion_status", 0)
    fmpy_compat.exit_without_finalizers(status)


def pytest_sessionfinish(session, exitstatus):
    session.config._flexfusion_status = int(exitstatus)
