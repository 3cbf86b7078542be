"""Slow, obviously-correct reference implementations the fast weather code is tested against."""
