"""Serial bridge to the Arduino Due rig (Joint protocol), device emulator and firmware support."""
