"""Serial bridge to the Arduino Due rig (Joint protocol), device emulator and firmware support."""
import cartpole_core  # noqa: F401,E402 - pins numerical threads to one before numpy loads
