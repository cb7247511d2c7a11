"""ilcforce: iterative learning control experiments for hybrid force/position control."""

__version__ = "0.1.0"
