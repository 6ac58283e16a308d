"""mcverify: Monte-Carlo verification and falsification of VL-CBF / TO-CBF-MPC overtaking controllers."""

__version__ = "0.1.0"
