"""What: the named effect catalogue and each effect's term."""
