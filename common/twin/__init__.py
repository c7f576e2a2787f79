"""A real robot's twin: its motion model (motion.py) and the fit from its recordings (fit.py).

A library with no network: ``wart calibrate`` (services/commands/calibrate.py) reads
recordings and calls it; services/bridge/rehearse.py makes recordings to test it on.
"""
