"""`lads diagnose`: locate where simulated and real LiDAR recordings differ, name the physics
the simulation left out, fit it, and show the held-out fit improve (docs/diagnose.md)."""
