"""Verdict: stability, ambiguity sets, the final fit and its intervals, the noise model."""
