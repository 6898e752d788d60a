"""cartpole_hw tests: hypothesis keeps no example database in the work tree."""
import pytest
from hypothesis import settings

settings.register_profile('cartpole_hw', database=None, deadline=None)
settings.load_profile('cartpole_hw')


@pytest.fixture(scope='session')
def firmware_image():
    """The firmware compiled for the Cortex-M3 (``make -C firmware arm-image``), built once a
    session; skips, naming the Debian packages, where the ARM toolchain or QEMU is missing."""
    from cartpole_hw.qemu_board import build_image, missing_message, missing_packages
    missing = missing_packages()
    if missing:
        pytest.skip(missing_message(missing))
    return build_image()
