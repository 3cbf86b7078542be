"""Data: open the trees, pair the returns, reduce them to the beam table."""
