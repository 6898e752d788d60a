"""The rig's device emulated: the simulated plant behind the Joint protocol on a pseudo-terminal, in Python or as the firmware on a Cortex-M3 in QEMU."""
import cartpole_core  # noqa: F401,E402 - pins numerical threads to one before numpy loads
