"""Training: BC / BC-RL / DAgger / ADVISOR updates, the training loop and its commands."""
