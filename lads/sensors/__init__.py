"""Sensor profiles: data files (YAML) describing each LiDAR, loaded into `SensorProfile`."""

from lads.sensors.profile import IntensityEncoding, SensorProfile, available_profiles, load_profile

__all__ = ["IntensityEncoding", "SensorProfile", "available_profiles", "load_profile"]
