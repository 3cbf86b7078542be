"""Sensor transfer: a scan as another LiDAR would have recorded it (docs/transfer.md)."""
