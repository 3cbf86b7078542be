"""Select: held-out splits by spatial group, forward/backward selection on held-out gains."""
