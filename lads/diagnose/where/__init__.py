"""Where: bin the mismatch by feature, test the bins, state where it lies."""
