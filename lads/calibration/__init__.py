"""Calibration of the weather models against real recordings (WADS snow, RADIATE fog).

Pure functions; the only file reading is in the small `load_*` helpers, which take explicit
paths. The benchmarks in `benchmarks/wads_snow.py` and `benchmarks/fog_radiate.py` run them.
"""
