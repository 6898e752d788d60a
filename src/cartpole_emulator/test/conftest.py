"""cartpole_emulator tests: the firmware image for the QEMU board, built once a session."""
import pytest


@pytest.fixture(scope='session')
def firmware_image():
    """The firmware compiled for the Cortex-M3 (``make -C firmware arm-image``), built once a
    session; skips, naming the Debian packages, where the ARM toolchain or QEMU is missing."""
    from cartpole_emulator.qemu_board import build_image, missing_message, missing_packages
    missing = missing_packages()
    if missing:
        pytest.skip(missing_message(missing))
    return build_image()
