"""IGDrivSim: a JAX benchmark for the imitation gap in autonomous driving."""

__version__ = "0.1.0"
