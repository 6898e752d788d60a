"""Controller manager with swing-up and stabiliser plugins, catch trigger and friction feedforward."""
