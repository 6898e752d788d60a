"""Controller manager with swing-up and stabiliser plugins, catch trigger and friction feedforward."""
import cartpole_core  # noqa: F401,E402 - pins numerical threads to one before numpy loads
