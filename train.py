"""Training entry point (LightningCLI). Filled in by the neural-parser work."""
